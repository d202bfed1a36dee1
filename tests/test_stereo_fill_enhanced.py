"""The stereo fill-in on frames the enhancement changed (tracking.stereo_fill_enhanced_min_sigma,
canopy.frontend.stereo_fill.enhanced_fill_active; issue 9's dim hazy noisy cells, docs/notes/s19-dimfill.md).

A real KITTI 06 pair from ``data/`` gets the grid's low light (x0.15) and haze (beta 0.06 /m, depth from SGBM
on the clean pair) with the noisy sensor, or the same light and haze without sensor noise, and goes through
the enhancement as the actors run it (``PairEnhancer``, ``auto``: AFE then the denoiser). The gate must
open on the noisy enhanced pair only; where it opens, the fill-in must keep every descriptor match and add
matches whose disparities agree with the clean pair's SGBM disparity; off (the default), the matcher's
output is the descriptor matcher's, bit for bit.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image, depth_from_stereo, ray_length
from canopy.enhance import tracking_fast_arguments
from canopy.enhance.pair import PairEnhancer
from canopy.frontend.noisy_features import tracking_extractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import match_stereo
from canopy.frontend.stereo_fill import enhanced_fill_active, fill_active
from canopy.sources import open_source
from shared.errors import ConfigError
from tests.test_stereo_fill import filled_against_sgbm

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"
# KITTI's enhanced pair measures robust 0.88 (noisy sensor) against 0.23 (no sensor noise); the generated
# orchards' own fine texture lifts both (configs/synthetic.yaml's value is for those)
GATE = dict(stereo_fill=True, stereo_fill_enhanced_min_sigma=0.5, stereo_fill_enhanced_max_texture=2.0)


def _params(**kw):
    return replace(load_run_config("synthetic").tracking, parallel_extraction=False, **kw)


def _enhanced_pair(noisy: bool, frame_index: int = 20):
    src = open_source("kitti", KITTI)
    f = src.frame(frame_index)
    ray = ray_length(depth_from_stereo(f.left, f.right, src.calibration), src.calibration)
    level = NOISE_LEVELS["high"] if noisy else (1e9, 0.0)
    cell = DegradeParams(mode="dark+haze", gain=0.15, beta=0.06, full_well=level[0], read_noise=level[1])
    left, right = degrade_image(f.left, cell, ray, rng=0), degrade_image(f.right, cell, ray, rng=1)
    enh = PairEnhancer(replace(load_run_config("synthetic").enhancement, method="auto"), parallel=False)
    try:
        le, re, info = enh(left, right)
    finally:
        enh.close()
    return src, f, le, re, info


def _matches(params, left_img, right_img, calib):
    # an enhanced frame: the tracking actor's FAST arguments (AFE Eq. 18 / 19), so the extractor
    # measures no robust sigma
    fast = tracking_fast_arguments(left_img, "afe>dn", load_run_config("synthetic").enhancement, params.n_features)
    args = (fast["fast_threshold"], fast["fast_fallback"], fast["fast_min_keypoints"])
    fl = tracking_extractor(params, responses=False).extract(left_img, *args)
    fr = tracking_extractor(params, responses=False).extract(right_img, *args)
    assert fl.robust_noise_sigma is None
    return fl, match_stereo(fl, fr, left_img, right_img, calib, params)


def test_off_by_default_and_refused_when_negative():
    assert TrackingParams().stereo_fill_enhanced_min_sigma == 0.0
    assert load_run_config("kitti").tracking.stereo_fill_enhanced_min_sigma == 0.0
    assert load_run_config("euroc").tracking.stereo_fill_enhanced_min_sigma == 0.0
    for bad in ({"stereo_fill_enhanced_min_sigma": -1.0}, {"stereo_fill_enhanced_max_sigma": -1.0},
                {"stereo_fill_enhanced_max_texture": -0.5}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            replace(TrackingParams(), **bad).validate()


def test_synthetic_config_keeps_the_raw_rule_and_leaves_the_enhanced_gate_off():
    t = load_run_config("synthetic").tracking
    assert (t.stereo_fill, t.stereo_fill_min_sigma) == (True, 5.5)           # the raw-frame rule
    assert t.stereo_fill_enhanced_min_sigma == 0.0                           # off: see configs/synthetic.yaml


def test_gate_opens_on_the_noisy_enhanced_pair_only():
    _, _, noisy, _, info_n = _enhanced_pair(True)
    _, _, quiet, _, info_q = _enhanced_pair(False)
    assert info_n["method"].endswith(">dn") and info_q["method"] != "none"   # both enhanced
    p = _params(**GATE)
    assert enhanced_fill_active(noisy, p)
    assert not enhanced_fill_active(quiet, p)
    assert not enhanced_fill_active(None, p)   # no image: no fill-in
    # the upper bound (the clean haze-row's dehazed frames measure 5.4-5.7)
    assert not enhanced_fill_active(noisy, replace(p, stereo_fill_enhanced_max_sigma=0.6))
    assert enhanced_fill_active(noisy, replace(p, stereo_fill_enhanced_max_sigma=4.0))
    # the texture test: the same image with a 0 grey-level texture allowance is refused
    assert not enhanced_fill_active(noisy, replace(p, stereo_fill_enhanced_max_texture=1e-6))


def test_fill_on_the_enhanced_noisy_pair_adds_good_matches():
    src, clean, left, right, _ = _enhanced_pair(True)
    calib = src.calibration
    off = _params(stereo_fill=False)
    on = _params(**GATE)
    fl, base = _matches(off, left, right, calib)
    assert fill_active(fl, on, left)
    assert not fill_active(fl, _params(stereo_fill=True, stereo_fill_min_sigma=5.5), left)  # the old rule: shut
    fl2, filled = _matches(on, left, right, calib)
    np.testing.assert_array_equal(fl2.uv, fl.uv)
    added, e_add, e_base, _ = filled_against_sgbm(fl, base, filled, clean)
    assert added.sum() >= 0.2 * base.valid.sum()
    # the added disparities are about as good as the descriptor matcher's against the clean SGBM
    assert np.median(e_add) <= 1.25 * np.median(e_base) + 0.1
    # with the rule off the output is the descriptor matcher's, bit for bit
    _, same = _matches(_params(stereo_fill=True, stereo_fill_min_sigma=5.5), left, right, calib)
    np.testing.assert_array_equal(same.u_right, base.u_right)
    np.testing.assert_array_equal(same.depth, base.depth)
