"""The stereo fill-in on frames the enhancement changed, gated by the enhancement's own noise sigma of the
frame (tracking.stereo_fill_enhanced_min_sensor_sigma, canopy.frontend.stereo_fill.sensor_fill_open; issue 9's
dim noisy cells, docs/notes/s20-dimsigma.md).

A real KITTI 06 pair from ``data/`` gets the grid's low light (x0.15) and haze (beta 0.06 /m, depth from SGBM
on the clean pair) with the noisy sensor, or the same light and haze without sensor noise, and goes through
the enhancement as the actors run it (``PairEnhancer``, ``auto``: AFE then the denoiser, whose sigma is the
figure handed to the tracker). The gate must open on the noisy pair only; where it opens, the fill-in keeps
every descriptor match and adds matches whose disparities agree with the clean pair's SGBM; the tracker gets
the figure through ``extract`` / ``track`` on both of its stereo paths, and the tracking actor takes it from
the frame message's enhancement info.
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
from canopy.frontend import Tracker
from canopy.frontend.noisy_features import tracking_extractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import match_stereo
from canopy.frontend.stereo_fill import fill_active, fill_unmatched_by_flow, sensor_fill_open
from canopy.frontend.tracker_worker import frame_stereo
from canopy.sources import open_source
from protocol.codec import decode, encode
from protocol.messages import FrameHandle
from shared.errors import ConfigError
from shared.types import StereoFrame
from tests.test_stereo_fill import filled_against_sgbm

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"


def _params(**kw):
    return replace(load_run_config("synthetic").tracking, **{"parallel_extraction": False, **kw})


def _gate(**kw):
    return _params(**{"stereo_fill": True, "stereo_fill_enhanced_min_sensor_sigma": 11.0, **kw})


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


def _fast(left_img, params):
    # an enhanced frame: the tracking actor's FAST arguments (AFE Eq. 18 / 19), so the extractor measures
    # no robust sigma
    return tracking_fast_arguments(left_img, "afe>dn", load_run_config("synthetic").enhancement, params.n_features)


def _features(params, left_img, right_img):
    f = _fast(left_img, params)
    args = (f["fast_threshold"], f["fast_fallback"], f["fast_min_keypoints"])
    fl = tracking_extractor(params, responses=False).extract(left_img, *args)
    fr = tracking_extractor(params, responses=False).extract(right_img, *args)
    assert fl.robust_noise_sigma is None
    return fl, fr


def test_off_by_default_and_refused_when_negative():
    assert TrackingParams().stereo_fill_enhanced_min_sensor_sigma == 0.0
    for config in ("kitti", "euroc"):
        assert load_run_config(config).tracking.stereo_fill_enhanced_min_sensor_sigma == 0.0
    for bad in ({"stereo_fill_enhanced_min_sensor_sigma": -1.0}, {"stereo_fill_enhanced_max_sensor_sigma": -1.0}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            replace(TrackingParams(), **bad).validate()


def test_synthetic_config_opens_it_above_the_clean_presets():
    t = load_run_config("synthetic").tracking
    assert (t.stereo_fill, t.stereo_fill_min_sigma) == (True, 5.5)           # the raw-frame rule, as before
    # every frame of the clean presets: the enhancement's sigma <= 9.21; the grid's dim noisy cells >= 13.49
    assert 9.21 < t.stereo_fill_enhanced_min_sensor_sigma < 13.49
    assert t.stereo_fill_enhanced_max_sensor_sigma == 0.0


def test_the_band_and_the_missing_figure():
    p = _gate()
    assert sensor_fill_open(11.0, p) and sensor_fill_open(40.0, p)       # [min, unbounded)
    assert not sensor_fill_open(10.99, p) and not sensor_fill_open(0.0, p)
    assert not sensor_fill_open(None, p)                                  # not handed over: no fill-in
    top = replace(p, stereo_fill_enhanced_max_sensor_sigma=16.0)
    assert sensor_fill_open(15.9, top) and not sensor_fill_open(16.0, top)


def test_gate_opens_on_the_noisy_enhanced_pair_only():
    _, _, noisy, quiet_r, info_n = _enhanced_pair(True)
    _, _, quiet, _, info_q = _enhanced_pair(False)
    assert info_n["method"].endswith(">dn") and info_q["method"].endswith(">dn")   # both denoised
    p = _gate()
    fl, _ = _features(p, noisy, quiet_r)
    assert fill_active(fl, p, noisy, None, info_n["noise_sigma"])
    assert not fill_active(fl, p, quiet, None, info_q["noise_sigma"])   # the dark floor (4), no sensor noise
    assert not fill_active(fl, p, noisy, None, None)
    assert not fill_active(fl, replace(p, stereo_fill=False), noisy, None, info_n["noise_sigma"])


def test_fill_on_the_noisy_pair_adds_good_matches_and_is_match_stereos_fill():
    src, clean, left, right, info = _enhanced_pair(True)
    calib, p = src.calibration, _gate()
    fl, fr = _features(p, left, right)
    scale = p.scale_factor ** np.arange(p.n_levels)
    frame = StereoFrame(0, 0.0, left, right)
    base = match_stereo(fl, fr, left, right, calib, p)                   # no figure: the descriptor matches
    shut = frame_stereo(fl, fr, frame, calib, p, scale, None, sensor_sigma=4.0)
    np.testing.assert_array_equal(shut.u_right, base.u_right)           # gate shut: bit for bit
    np.testing.assert_array_equal(shut.depth, base.depth)
    filled = frame_stereo(fl, fr, frame, calib, p, scale, None, sensor_sigma=info["noise_sigma"])
    same = fill_unmatched_by_flow(base, fl, left, right, calib, p, None)
    np.testing.assert_array_equal(filled.depth, same.depth)             # exactly the fill-in match_stereo runs
    added, e_add, e_base, _ = filled_against_sgbm(fl, base, filled, clean)
    assert added.sum() >= 0.2 * base.valid.sum()
    assert np.median(e_add) <= 1.25 * np.median(e_base) + 0.1


@pytest.mark.parametrize("parallel", [False, True])
def test_tracker_hands_the_figure_to_its_stereo(parallel):
    src, _, left, right, info = _enhanced_pair(True)
    p = _gate(parallel_extraction=parallel, parallel_stereo=parallel)
    fast = _fast(left, p)
    counts = {}
    for sigma in (None, 4.0, info["noise_sigma"]):
        res = Tracker(src.calibration, p).track(StereoFrame(0, 0.0, left, right), **fast, sensor_sigma=sigma)
        counts[sigma] = res.n_stereo
    assert counts[None] == counts[4.0]
    assert counts[info["noise_sigma"]] >= counts[None] * 1.2


def test_the_tracking_actor_takes_the_figure_from_the_frame_message():
    from actors.tracking import TrackingActor

    actor = TrackingActor.__new__(TrackingActor)
    actor.adaptive_fast, actor.hands_sensor_sigma = False, True
    frame = StereoFrame(0, 0.0, np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8))
    handle = FrameHandle(index=0, timestamp=0.0, ring="r", slot=0, generation=1, sent_at=0.0,
                         info={"method": "afe>dn", "noise_sigma": 15.5})
    handle = decode(encode(handle))                                    # as it crosses the process boundary
    assert actor._frame_arguments(frame, handle) == {"sensor_sigma": 15.5}
    assert actor._frame_arguments(frame, replace(handle, info={})) == {}   # no enhancement info: no figure
    actor.hands_sensor_sigma = False                                  # the mono tracker
    assert actor._frame_arguments(frame, handle) == {}
