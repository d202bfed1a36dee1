"""Sub-pixel stereo refinement on a smoothed pair for noisy frames (issue 9, tracking.subpixel_denoise_sigma).

A real KITTI 06 pair from ``data/`` gets the grid's noisy sensor (full well 1000 e-, read noise 10);
keypoints and descriptor matches are those of the noisy pair. The reference disparity of each
match is the SAD refinement of the same match on the clean pair. Refining on the smoothed noisy
pair must land closer to it than refining on the raw noisy pair, and a clean pair (noise σ below
the threshold) must come out exactly as with the rule off.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.noisy_features import refinement_pair
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import match_stereo
from canopy.sources import open_source
from shared.errors import ConfigError

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"
FRAMES = (5, 20, 35)


def _noisy(image: np.ndarray, seed: int) -> np.ndarray:
    cell = DegradeParams(mode="noise", full_well=NOISE_LEVELS["high"][0], read_noise=NOISE_LEVELS["high"][1])
    return degrade_image(image, cell, rng=seed)


def test_refinement_pair_is_the_raw_pair_when_off_or_clean():
    src = open_source("kitti", KITTI)
    f = src.frame(FRAMES[0])
    left, right, sigma = refinement_pair(f.left, f.right, TrackingParams())
    assert left is f.left and right is f.right and sigma is None          # off by default
    on = TrackingParams(subpixel_denoise_sigma=4.0)
    left, right, sigma = refinement_pair(f.left, f.right, on)
    assert left is f.left and right is f.right and 1.0 < sigma < 3.0      # clean KITTI measures ~1.8
    nl, nr = _noisy(f.left, 0), _noisy(f.right, 1)
    left, right, sigma = refinement_pair(nl, nr, on)
    assert sigma > 4.0 and left is not nl and right is not nr
    # the same symmetric smoothing on both images: flat noise is averaged away
    assert np.std(left.astype(float) - nl) > 2.0
    for bad in ({"subpixel_denoise_sigma": -1.0}, {"subpixel_denoise_blur": -0.5}):
        with pytest.raises(ConfigError, match="subpixel_denoise"):
            TrackingParams(**bad)


def test_smoothed_refinement_halves_the_disparity_noise_without_a_bias():
    """The disparity noise is the difference between a match's refinement on the noisy pair and on
    the clean pair *with the same estimator* (both raw, or both smoothed): the smoothing must cut
    it, and on the clean pair the smoothed estimator must not move the disparities on average (a
    mean shift would change the scale against the calibrated disparity offset)."""
    src = open_source("kitti", KITTI)
    # the smoothed pair's own vertex (configs/kitti.yaml takes the raw pair's since s31: the next test)
    base = replace(load_run_config("kitti").tracking, parallel_extraction=False, subpixel_raw_vertex_search=0)
    on = replace(base, subpixel_denoise_sigma=4.0, subpixel_denoise_blur=1.5)
    always = replace(on, subpixel_denoise_sigma=1e-3)   # smooth the clean pair too: the same estimator
    noise_raw, noise_dn, shift, n_raw, n_dn = [], [], [], 0, 0
    for i in FRAMES:
        f = src.frame(i)
        nl, nr = _noisy(f.left, 2 * i), _noisy(f.right, 2 * i + 1)
        fl, fr = CellExtractor(base).extract(nl), CellExtractor(base).extract(nr)
        raw = match_stereo(fl, fr, nl, nr, src.calibration, base)
        dn = match_stereo(fl, fr, nl, nr, src.calibration, on)
        ref = match_stereo(fl, fr, f.left, f.right, src.calibration, base)      # same matches, clean pixels
        ref_dn = match_stereo(fl, fr, f.left, f.right, src.calibration, always)
        both = raw.valid & dn.valid & ref.valid & ref_dn.valid
        noise_raw.append(raw.u_right[both] - ref.u_right[both])
        noise_dn.append(dn.u_right[both] - ref_dn.u_right[both])
        shift.append(ref_dn.u_right[both] - ref.u_right[both])
        n_raw += int(raw.valid.sum())
        n_dn += int(dn.valid.sum())
    e_raw, e_dn = np.abs(np.concatenate(noise_raw)), np.abs(np.concatenate(noise_dn))
    assert len(e_raw) > 300, len(e_raw)
    # measured (3 frames, 1488 matches): median |noise| 0.080 -> 0.052 px, share > 0.5 px 11 -> 4 %
    assert np.median(e_dn) < 0.8 * np.median(e_raw), (np.median(e_raw), np.median(e_dn))
    assert np.mean(e_dn > 0.5) < 0.6 * np.mean(e_raw > 0.5), (np.mean(e_raw > 0.5), np.mean(e_dn > 0.5))
    # the estimator itself: no mean shift on clean pixels (measured +0.03 px in u_right)
    assert abs(float(np.mean(np.clip(np.concatenate(shift), -2, 2)))) < 0.06
    assert n_dn > 0.9 * n_raw, (n_raw, n_dn)        # the smoothed pair does not lose the matches


def test_raw_vertex_around_the_smoothed_minimum_removes_the_blurs_depth_band_bias():
    """tracking.subpixel_raw_vertex_search (s31): the Gaussian before the SAD moves the vertex by depth
    band (KITTI's 8-20 px points read ~-0.07 px at blur 2 on the noisy sensor, which lengthens the path);
    taking only the whole-pixel minimum from the smoothed pair and the vertex from the raw pair's SAD
    around it must bring that band's mean shift against the clean pair's refinement near 0, and cut the
    matches > 1 px off, without losing more than a tenth of the matches."""
    src = open_source("kitti", KITTI)
    vertex = replace(load_run_config("kitti").tracking, parallel_extraction=False)
    assert vertex.subpixel_denoise_sigma > 0 and vertex.subpixel_denoise_blur == 2.0
    assert vertex.subpixel_raw_vertex_search == 2                        # on in configs/kitti.yaml
    base = replace(vertex, subpixel_raw_vertex_search=0)                  # the smoothed pair's vertex
    shift = {"blur": [], "raw": []}
    disp, valid = [], {"blur": 0, "raw": 0}
    for i in range(0, 50, 5):
        f = src.frame(i)
        nl, nr = _noisy(f.left, 2 * i), _noisy(f.right, 2 * i + 1)
        fl, fr = CellExtractor(base).extract(f.left), CellExtractor(base).extract(f.right)
        ref = match_stereo(fl, fr, f.left, f.right, src.calibration, base)   # clean pair: raw SAD
        runs = {"blur": match_stereo(fl, fr, nl, nr, src.calibration, base),
                "raw": match_stereo(fl, fr, nl, nr, src.calibration, vertex)}
        both = ref.valid & runs["blur"].valid & runs["raw"].valid
        for k, m in runs.items():
            shift[k].append(ref.u_right[both] - m.u_right[both])   # noisy - clean disparity
            valid[k] += int(m.valid.sum())
        disp.append(fl.uv[both, 0] - ref.u_right[both])
    d = np.concatenate(disp)
    mid = (d >= 8) & (d < 20)
    stats = {}
    for k in shift:
        s = np.concatenate(shift[k])
        stats[k] = (float(np.mean(s[mid & (np.abs(s) < 2)])), float(np.mean(np.abs(s) > 1.0)))
    assert mid.sum() > 400, mid.sum()
    assert stats["blur"][0] < -0.04, stats            # the bias the option removes is there
    assert abs(stats["raw"][0]) < 0.025, stats
    assert stats["raw"][1] < 0.6 * stats["blur"][1], stats
    assert valid["raw"] > 0.9 * valid["blur"], valid
    # the clean pair is under the smoothing gate: the option changes nothing there
    f = src.frame(0)
    fl, fr = CellExtractor(base).extract(f.left), CellExtractor(base).extract(f.right)
    a = match_stereo(fl, fr, f.left, f.right, src.calibration, base)
    b = match_stereo(fl, fr, f.left, f.right, src.calibration, vertex)
    assert np.array_equal(a.u_right, b.u_right)
    with pytest.raises(ConfigError, match="subpixel_raw_vertex_search"):
        replace(base, subpixel_raw_vertex_search=base.subpixel_search + 1)


def test_raw_pair_pyramids_are_prebuilt_when_the_raw_vertex_reads_them():
    """The stereo job builds the raw pair's SAD pyramids ahead only where the refinement will read them: a
    frame under the smoothing gate, or (with the raw vertex) any frame."""
    from types import SimpleNamespace

    from canopy.frontend.tracker_worker import raw_pair_likely

    noisy, clean = SimpleNamespace(robust_noise_sigma=6.0), SimpleNamespace(robust_noise_sigma=1.8)
    smoothed = TrackingParams(subpixel_denoise_sigma=4.0, subpixel_raw_vertex_search=0)
    vertex = TrackingParams(subpixel_denoise_sigma=4.0)   # the raw vertex is the default
    assert raw_pair_likely(clean, smoothed) and not raw_pair_likely(noisy, smoothed)
    assert raw_pair_likely(clean, vertex) and raw_pair_likely(noisy, vertex)
