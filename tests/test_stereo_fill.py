"""Stereo fill-in by LK flow for the keypoints the descriptor matcher leaves unmatched
(issue 9's lit hazy cells, tracking.stereo_fill, canopy.frontend.stereo_fill).

A real KITTI 06 pair from ``data/`` gets the grid's haze (beta 0.06 /m, depth from SGBM on the clean
pair, as tools/degrade_sequence.py) and its low-noise sensor. The fill-in must leave every descriptor
match as it was, add matches whose disparities agree with the clean pair's SGBM disparity, and
recover far (> 20 m) stereo points the descriptor matcher lost; outside its noise band (a clean pair)
the matcher's output must be exactly the descriptor matcher's.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.degrade import (NOISE_LEVELS, DegradeParams, degrade_image, depth_from_stereo, disparity_sgbm,
                            ray_length)
from canopy.frontend.noisy_features import tracking_extractor
from canopy.frontend.stereo import StereoMatches, match_stereo
from canopy.frontend.stereo_fill import fill_active, fill_unmatched_by_flow
from canopy.sources import open_source
from shared.errors import ConfigError

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"


def _params(**kw):
    # the fill-in alone: KITTI's zero-mean SAD on the fill-in's frames (subpixel_mean_on_fill) would move
    # the descriptor matches' refinement too (tests/test_stereo_mean_on_fill.py tests it)
    base = replace(load_run_config("kitti").tracking, parallel_extraction=False, subpixel_mean_on_fill=False)
    return replace(base, **kw)


def _matches(params, left_img, right_img, calib):
    # the tracker's extractor (KITTI: the noise-gated cells extractor, which measures the robust sigma)
    ex_l, ex_r = tracking_extractor(params, responses=False), tracking_extractor(params, responses=False)
    fl, fr = ex_l.extract(left_img), ex_r.extract(right_img)
    return fl, match_stereo(fl, fr, left_img, right_img, calib, params)


def _hazy_pair(frame_index: int, level: str = "low"):
    src = open_source("kitti", KITTI)
    f = src.frame(frame_index)
    ray = ray_length(depth_from_stereo(f.left, f.right, src.calibration), src.calibration)
    cell = DegradeParams(mode="haze+noise", beta=0.06, full_well=NOISE_LEVELS[level][0],
                         read_noise=NOISE_LEVELS[level][1])
    return src, f, degrade_image(f.left, cell, ray, rng=0), degrade_image(f.right, cell, ray, rng=1)


RULE = dict(stereo_fill=True, stereo_fill_max_sigma=4.0, stereo_fill_max_texture=2.15)  # configs/kitti.yaml


def test_kitti_config_has_the_rule():
    t = load_run_config("kitti").tracking
    assert (t.stereo_fill, t.stereo_fill_min_sigma, t.stereo_fill_max_sigma, t.stereo_fill_max_texture) == \
        (True, 0.0, 4.0, 2.15)


def _noise_only(image: np.ndarray, level: str, seed: int) -> np.ndarray:
    cell = DegradeParams(mode="noise", full_well=NOISE_LEVELS[level][0], read_noise=NOISE_LEVELS[level][1])
    return degrade_image(image, cell, rng=seed)


@pytest.mark.parametrize("case", ["clean", "low-noise sensor, no haze", "noisy sensor, haze"])
def test_off_or_outside_the_rule_is_the_descriptor_matcher(case):
    """Clean and noise-only frames keep their texture (excess above the gate), the noisy sensor's
    hazy frame is above the sigma band: each gets exactly the descriptor matcher's matches."""
    src = open_source("kitti", KITTI)
    f = src.frame(20)
    if case == "clean":
        left, right = f.left, f.right
    elif case.startswith("low"):
        left, right = _noise_only(f.left, "low", 0), _noise_only(f.right, "low", 1)
    else:
        _, _, left, right = _hazy_pair(20, "high")
    off = _params(stereo_fill=False)
    fl, base = _matches(off, left, right, src.calibration)
    assert not fill_active(fl, off, left)
    on = _params(**RULE)
    assert not fill_active(fl, on, left)
    _, same = _matches(on, left, right, src.calibration)
    np.testing.assert_array_equal(same.u_right, base.u_right)
    np.testing.assert_array_equal(same.depth, base.depth)


def filled_against_sgbm(fl, base, filled, clean):
    """The fill-in's matches ``filled`` against the descriptor matcher's ``base`` on the same keypoints
    ``fl``: the descriptor matches must be untouched; returns the added matches' mask and the
    |disparity - the clean pair's SGBM disparity| of the added and of the descriptor matches, and that
    SGBM disparity at every keypoint (0: none)."""
    kept = base.valid
    np.testing.assert_array_equal(filled.u_right[kept], base.u_right[kept])   # descriptor matches untouched
    added = filled.valid & ~kept
    ref = disparity_sgbm(clean.left, clean.right).astype(np.float64)
    h, w = ref.shape
    uv = fl.uv
    d_ref = ref[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]

    def err(m):
        s = m & (d_ref > 0)
        return np.abs((uv[s, 0] - filled.u_right[s]) - d_ref[s])
    return added, err(added), err(kept), d_ref


def test_fill_recovers_far_stereo_points_of_a_hazy_pair():
    src, clean, left, right = _hazy_pair(20)
    calib = src.calibration
    off = _params(stereo_fill=False)
    on = _params(**RULE)
    fl, base = _matches(off, left, right, calib)
    assert 2.5 <= fl.robust_noise_sigma < 4.0            # the low-noise sensor: inside the band
    assert fill_active(fl, on, left)                     # and haze flattened the texture
    fl2, filled = _matches(on, left, right, calib)
    np.testing.assert_array_equal(fl2.uv, fl.uv)         # same keypoints
    added, e_add, e_base, d_ref = filled_against_sgbm(fl, base, filled, clean)
    assert added.sum() >= 0.3 * base.valid.sum()
    # the added disparities are as good as the descriptor matcher's, against the clean pair's SGBM
    # (itself ~0.5 px from the truth on KITTI: the figures compare, they are not absolute errors)
    assert np.median(e_add) <= 1.1 * np.median(e_base)
    assert np.mean(e_add > 1.0) <= np.mean(e_base > 1.0) + 0.05
    # far points (clean SGBM depth > 20 m): the fill-in matches more of them than the descriptors did
    far = (d_ref > 0) & (calib.bf / np.maximum(d_ref, 1e-6) > 20.0)
    assert (filled.valid & far).sum() >= 1.5 * (base.valid & far).sum()


def test_bad_inputs_are_refused_by_name():
    for bad in ({"stereo_fill_min_sigma": -1.0}, {"stereo_fill_max_sigma": -0.5}, {"stereo_fill_max_texture": -2.0}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            _params(**bad).validate()
    src = open_source("kitti", KITTI)
    f = src.frame(0)
    p = _params(stereo_fill=True)
    fl, _ = _matches(_params(stereo_fill=False), f.left, f.right, src.calibration)
    short = StereoMatches(np.full(3, -1.0, np.float32), np.full(3, -1.0, np.float32))
    with pytest.raises(ValueError, match="fill_unmatched_by_flow: matches"):
        fill_unmatched_by_flow(short, fl, f.left, f.right, src.calibration, p)
