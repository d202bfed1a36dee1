"""Stereo matching by LK flow (tracking.stereo_matcher: flow, canopy.frontend.stereo_flow).

The pair is rendered with an exact sub-pixel disparity: a random texture at 8x the image resolution,
the left image its area-average, the right image the area-average of the texture shifted by k texels
(disparity k / 8 px on every pixel). The flow matcher must recover it within a small fraction of a
pixel on most keypoints; the tracker must track real KITTI frames with it without the right ORB.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.frontend import Tracker
from canopy.frontend.cell_extractor import make_extractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import match_stereo
from canopy.frontend.stereo_flow import flow_right_columns, match_stereo_flow
from canopy.sources import open_source
from shared.errors import ConfigError
from shared.types import StereoCalibration

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"
W, H, UP = 480, 240, 8


def _pair(shift_texels: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    coarse = rng.uniform(0, 255, (H * UP // 16, (W + 64) * UP // 16)).astype(np.float32)
    texture = cv2.resize(coarse, None, fx=16, fy=16, interpolation=cv2.INTER_CUBIC)
    texture = cv2.GaussianBlur(texture, (0, 0), 6.0)
    texture = cv2.normalize(texture, None, 10, 245, cv2.NORM_MINMAX)

    def render(x0: int) -> np.ndarray:
        crop = texture[:, x0:x0 + W * UP]
        return np.clip(cv2.resize(crop, (W, H), interpolation=cv2.INTER_AREA) + 0.5, 0, 255).astype(np.uint8)

    # right(x) = left(x + d): the right image's window starts d px further right in the texture
    return render(0), render(shift_texels)


CALIB = StereoCalibration(fx=400.0, fy=400.0, cx=W / 2, cy=H / 2, baseline=0.5, width=W, height=H)


@pytest.mark.parametrize("shift_texels", [187, 43])   # 23.375 px and 5.375 px
def test_flow_recovers_an_exact_subpixel_disparity(shift_texels):
    d = shift_texels / UP
    left_img, right_img = _pair(shift_texels)
    params = TrackingParams(stereo_matcher="flow", n_features=800)
    feats = make_extractor(params).extract(left_img)
    assert len(feats) > 300
    # the LK columns themselves: a few hundredths of a pixel
    u_flow, found = flow_right_columns(left_img, right_img, feats.uv.astype(np.float64), params, W / 2)
    inside = feats.uv[:, 0] > d + 12  # keypoints whose match is inside the right image
    assert found.sum() >= 0.6 * inside.sum()
    assert np.median(np.abs(feats.uv[found, 0] - u_flow[found] - d)) < 0.05
    # after the SAD parabola refinement (its pixel locking: ~0.12 px at a fraction of 0.375 px)
    stereo = match_stereo_flow(feats, left_img, right_img, CALIB, params)
    ok = stereo.valid
    assert ok.sum() >= 0.6 * inside.sum()
    err = np.abs(feats.uv[ok, 0] - stereo.u_right[ok] - d)
    assert np.median(err) < 0.2 and np.percentile(err, 95) < 0.5
    np.testing.assert_allclose(stereo.depth[ok], CALIB.bf / (feats.uv[ok, 0] - stereo.u_right[ok]), rtol=1e-5)
    # the dispatcher: match_stereo with the flow matcher needs no right keypoints
    via = match_stereo(feats, None, left_img, right_img, CALIB, params)
    np.testing.assert_array_equal(via.u_right, stereo.u_right)


def test_flow_rejects_points_off_the_row_and_failed_back_tracks():
    left_img, _ = _pair(0)
    params = TrackingParams(stereo_matcher="flow")
    uv = np.array([[200.0, 120.0], [300.0, 100.0]])
    # the right image is the left one moved 3 px down: every flow leaves its row
    down = np.roll(left_img, 3, axis=0)
    _, ok = flow_right_columns(left_img, down, uv, params, 200.0)
    assert not ok.any()
    # an unrelated right image: the flow lands somewhere, the back-track does not return
    other, _ = _pair(0, seed=5)
    _, ok_other = flow_right_columns(left_img, other, np.array(np.meshgrid(np.arange(40, 440, 20.0),
                                                                           np.arange(40, 200, 20.0))).reshape(2, -1).T,
                                     params, 200.0)
    assert ok_other.mean() < 0.2
    with pytest.raises(ValueError, match="right_img"):
        flow_right_columns(left_img, np.dstack([left_img] * 3), uv, params, 200.0)
    with pytest.raises(ConfigError, match="stereo_matcher"):
        TrackingParams(stereo_matcher="sgbm")


def test_tracker_tracks_kitti_with_the_flow_matcher_without_the_right_orb():
    src = open_source("kitti", KITTI)
    params = replace(load_run_config("kitti").tracking, stereo_matcher="flow")
    tracker = Tracker(src.calibration, params)
    for i in range(4):
        res = tracker.track(src.frame(i))
        assert res.n_stereo > 300
        assert res.timings.get("orb_right_cpu", 0.0) < 1.0   # no right-image extraction
    assert res.status == "ok"
