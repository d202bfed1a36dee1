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
    base = replace(load_run_config("kitti").tracking, parallel_extraction=False)
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
