"""Zero-mean SAD on the frames the stereo fill-in gate opens on (tracking.subpixel_mean_on_fill,
canopy.frontend.stereo; issue 9's held-out lighter-haze cells, docs/notes/s21-hazedepth.md).

A real KITTI 06 pair from ``data/`` gets the held-out grid's lighter haze (beta 0.03 /m, depth from SGBM on
the clean pair, as tools/degrade_sequence.py) and the low-noise sensor, the cell whose trajectory was
over issue 9's bar. On that pair the centre-pixel SAD's minimum jumps by whole pixels (the centre pixel's
noise shifts every difference of a low-contrast patch); with the switch the stereo matches must agree
better with the clean pair's disparities, and a clean pair (the gate closed) must keep exactly the
matches it had.

The same on the hazy frames of the noisy sensor (tracking.subpixel_mean_on_noisy_haze, stereo_fill.mean_on_noisy_haze;
issue 9's KITTI g1-b0.06-high, docs/notes/s24-kittinoisy.md): the refinement runs on the Gaussian-smoothed pair and
the fill-in's gate is shut there; with the switch the matches of a hazed noisy pair agree better with the clean
pair's disparities, and the same sensor without haze (its texture excess stays above the haze test) and the clean
pair keep exactly the matches they had.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy.config import ConfigError, load_run_config
from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image, depth_from_stereo, disparity_sgbm, ray_length
from canopy.frontend.noisy_features import tracking_extractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import match_stereo
from canopy.frontend.stereo_fill import fill_active, mean_on_noisy_haze
from canopy.sources import open_source

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"


def _params(**kw):
    """configs/kitti.yaml's tracking settings with the noisy-haze SAD off unless asked for (the tests compare it)."""
    return replace(load_run_config("kitti").tracking, parallel_extraction=False,
                   **{"subpixel_mean_on_noisy_haze": False, **kw})


def _pair(frame_index: int, beta: float, noise: str | None = "low"):
    """The clean frame and the pair with haze beta (0: none) and the grid's ``noise`` sensor (None and beta 0:
    the clean pair)."""
    src = open_source("kitti", KITTI)
    f = src.frame(frame_index)
    if beta == 0 and noise is None:
        return src, f, f.left, f.right
    ray = ray_length(depth_from_stereo(f.left, f.right, src.calibration), src.calibration)
    full_well, read_noise = NOISE_LEVELS[noise]
    cell = DegradeParams(mode="haze+noise" if beta > 0 else "noise", beta=beta or 0.05, full_well=full_well,
                         read_noise=read_noise)
    return src, f, degrade_image(f.left, cell, ray, rng=0), degrade_image(f.right, cell, ray, rng=1)


def _matches(params, left_img, right_img, calib):
    ex_l, ex_r = tracking_extractor(params, responses=False), tracking_extractor(params, responses=False)
    fl, fr = ex_l.extract(left_img), ex_r.extract(right_img)
    return fl, match_stereo(fl, fr, left_img, right_img, calib, params)


def _errors(fl, st, clean):
    """|disparity - the clean pair's SGBM disparity| of the valid matches where SGBM has one. The rig's
    disparity offset (configs/kitti.yaml, which match_stereo adds) is taken out again: SGBM's disparities
    carry none, and the comparison is of the two refinements, not of the calibration."""
    ref = disparity_sgbm(clean.left, clean.right).astype(np.float64)
    h, w = ref.shape
    uv = fl.uv
    d_ref = ref[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
    s = st.valid & (d_ref > 0)
    offset = _params().disparity_offset_for(fl.extractor)
    return np.abs((uv[s, 0] - st.u_right[s] - offset) - d_ref[s])


def test_off_by_default_on_in_kitti_only():
    """KITTI switches it on (s23: its lit hazy cells' scale bias); EuRoC and the presets were not measured
    with it and keep ORB-SLAM2's centre SAD."""
    assert TrackingParams().subpixel_mean_on_fill is False
    assert load_run_config("kitti").tracking.subpixel_mean_on_fill is True
    for name in ("euroc", "synthetic"):
        assert load_run_config(name).tracking.subpixel_mean_on_fill is False


@pytest.mark.parametrize("frame_index", [10, 30])
def test_hazy_pair_disparities_closer_to_the_clean_pair(frame_index):
    src, clean, left, right = _pair(frame_index, 0.03)
    off, on = _params(subpixel_mean_on_fill=False), _params(subpixel_mean_on_fill=True)
    fl, base = _matches(off, left, right, src.calibration)
    assert fill_active(fl, on, left)                     # the lighter haze opens the fill-in gate
    fl2, mean = _matches(on, left, right, src.calibration)
    np.testing.assert_array_equal(fl2.uv, fl.uv)         # the same keypoints, only the refinement differs
    e_off, e_on = _errors(fl, base, clean), _errors(fl, mean, clean)
    assert len(e_on) >= 0.95 * len(e_off)                # no fewer stereo points
    assert np.mean(e_on > 1.0) < 0.8 * np.mean(e_off > 1.0)
    assert np.median(e_on) < np.median(e_off)


@pytest.mark.parametrize("switch, noise", [("subpixel_mean_on_fill", None), ("subpixel_mean_on_noisy_haze", None),
                                           ("subpixel_mean_on_noisy_haze", "high")])
def test_pairs_outside_the_gate_keep_their_matches(switch, noise):
    """The clean pair (both switches) and the noisy sensor without haze (its texture excess is above the haze
    test) keep exactly the matches they had."""
    gate = {"subpixel_mean_on_fill": fill_active, "subpixel_mean_on_noisy_haze": mean_on_noisy_haze}[switch]
    src, _, left, right = _pair(20, 0.0, noise)
    off, on = _params(**{switch: False}), _params(**{switch: True})
    fl, base = _matches(off, left, right, src.calibration)
    assert not gate(fl, on, left)
    _, same = _matches(on, left, right, src.calibration)
    np.testing.assert_array_equal(same.u_right, base.u_right)
    np.testing.assert_array_equal(same.depth, base.depth)


def test_noisy_haze_switch_off_by_default_and_on_for_kitti_only():
    """KITTI g1-b0.06-high: better on 10 of 15 noise draws, worse on 5, median 72.8 -> 59.8 mm
    (docs/notes/s24-kittinoisy.md, s24-lead.md): on in configs/kitti.yaml, measured nowhere else."""
    assert TrackingParams().subpixel_mean_on_noisy_haze is False
    assert load_run_config("kitti").tracking.subpixel_mean_on_noisy_haze is True
    for name in ("euroc", "synthetic"):
        assert load_run_config(name).tracking.subpixel_mean_on_noisy_haze is False


def test_noisy_haze_switch_needs_the_noisy_gate_and_the_haze_test():
    with pytest.raises(ConfigError, match="subpixel_mean_on_noisy_haze"):
        _params(subpixel_mean_on_noisy_haze=True, stereo_fill_max_texture=0.0)
    with pytest.raises(ConfigError, match="subpixel_mean_on_noisy_haze"):
        _params(subpixel_mean_on_noisy_haze=True, subpixel_denoise_sigma=0.0)


@pytest.mark.parametrize("frame_index", [10, 30])
def test_hazy_noisy_pair_disparities_closer_to_the_clean_pair(frame_index):
    src, clean, left, right = _pair(frame_index, 0.06, "high")
    off, on = _params(), _params(subpixel_mean_on_noisy_haze=True)
    fl, base = _matches(off, left, right, src.calibration)
    assert fl.robust_noise_sigma >= off.subpixel_denoise_sigma  # the smoothed pair ...
    assert not fill_active(fl, off, left)                     # ... where the fill-in's gate is shut
    assert mean_on_noisy_haze(fl, on, left)
    fl2, mean = _matches(on, left, right, src.calibration)
    np.testing.assert_array_equal(fl2.uv, fl.uv)              # the same keypoints, only the refinement differs
    e_off, e_on = _errors(fl, base, clean), _errors(fl, mean, clean)
    assert len(e_on) >= 0.95 * len(e_off)                     # no fewer stereo points
    # measured 0.84 (frame 10), 0.64 (30) against SGBM without the rig's offset (s30; with the offset the
    # comparison had carried, 0.151 px: 0.74 / 0.57)
    assert np.mean(e_on > 1.0) < 0.9 * np.mean(e_off > 1.0)
    assert np.median(e_on) < np.median(e_off)
