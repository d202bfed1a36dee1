"""The gate of the vertical prior (``canopy.frontend.vertical_gate``; tracking.vertical_gate_ratio): the pitch/roll
sigma the far points give is the spread of the refined pose's tilt over noise draws, and the gate sends the up
where only near structure is seen and holds it back where far structure pins the rotation."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.frontend.geometry import project_stereo, se3_exp, se3_inv
from canopy.frontend.params import TrackingParams
from canopy.frontend.pose import refine_pose
from canopy.frontend.vertical_gate import attitude_prior_wanted, attitude_std_deg, weak_streak
from shared.errors import ConfigError
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=435.0, fy=435.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)
UP_CAM = np.array([0.0, -1.0, 0.0])   # camera y points down: the up is -y (pitch about x, roll about z)


def _scene(rng, n_near: int, n_far: int):
    """Camera-frame points: a near row (1-4 m) and far trees (20-60 m, beyond 40 baselines = 4.4 m)."""
    def pts(n, z0, z1):
        z = rng.uniform(z0, z1, n)
        u, v = rng.uniform(20, 732, n), rng.uniform(20, 460, n)
        return np.stack([(u - CALIB.cx) * z / CALIB.fx, (v - CALIB.cy) * z / CALIB.fy, z], 1)
    return np.concatenate([pts(n_near, 1.0, 4.0), pts(n_far, 20.0, 60.0)])


def _far(Pc):
    return Pc[:, 2] > 40 * CALIB.baseline


def test_far_points_attitude_sigma_is_the_refined_tilt_spread():
    """40 far points measured with 1 px noise: the bound predicts the spread of the refined pose's rotation
    about the axes perpendicular to the up (pitch, roll) over 150 noise draws within 20 %."""
    rng = np.random.default_rng(3)
    Pc = _scene(rng, 0, 40)
    T_true = se3_exp(np.r_[0.02, -0.03, 0.01, 0.5, 0.1, -0.2])            # T_cam_world
    X = (se3_inv(T_true) @ np.c_[Pc, np.ones(len(Pc))].T).T[:, :3]
    sigma = np.ones(len(Pc))
    has_right = np.ones(len(Pc), bool)
    predicted = attitude_std_deg(Pc, sigma, has_right, CALIB, UP_CAM)
    clean = project_stereo(T_true, X, CALIB)[0]
    tilts = []
    for _ in range(150):
        meas = clean + rng.normal(0, 1.0, clean.shape)
        est = refine_pose(T_true, X, meas, has_right, sigma, CALIB, 1, 10, 1e9, 1e9)
        dR = est.T_cam_world[:3, :3] @ T_true[:3, :3].T                  # left increment, camera frame
        w = np.degrees(np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / 2)
        tilts.append(w[[0, 2]])                                            # about x (pitch) and z (roll)
    spread = np.sqrt(np.linalg.eigvalsh(np.cov(np.array(tilts).T)).max())
    assert 0.8 * predicted < spread < 1.2 * predicted, (predicted, spread)
    assert 0.005 < predicted < 0.2                                          # ~ (1 px / fx) / sqrt(40) rad, x3 for translation


def test_gate_sends_the_up_only_where_no_far_structure_pins_the_rotation():
    rng = np.random.default_rng(5)
    up_sigma = 0.2
    near_only = _scene(rng, 300, 0)                     # a hazy row: nothing beyond 4.4 m
    open_sky = _scene(rng, 300, 150)                    # the same row with the far trees visible
    for Pc, expect in ((near_only, True), (open_sky, False)):
        f = _far(Pc)
        vision = attitude_std_deg(Pc[f], np.ones(f.sum()), np.ones(f.sum(), bool), CALIB, UP_CAM)
        assert attitude_prior_wanted(vision, up_sigma, ratio=0.6) is expect, vision
    # all points (near ones included) pin the pitch/roll far more tightly than the far ones alone
    f = _far(open_sky)
    n = len(open_sky)
    assert (attitude_std_deg(open_sky, np.ones(n), np.ones(n, bool), CALIB, UP_CAM)
            < attitude_std_deg(open_sky[f], np.ones(f.sum()), np.ones(f.sum(), bool), CALIB, UP_CAM))
    # a few far points: their sigma is large and the up is wanted; none: infinite
    few = _scene(rng, 300, 4)
    f = _far(few)
    assert attitude_std_deg(few[f], np.ones(f.sum()), np.ones(f.sum(), bool), CALIB, UP_CAM) > 0.6 * up_sigma
    assert attitude_std_deg(few[:0], np.ones(0), np.ones(0, bool), CALIB, UP_CAM) == np.inf
    # ratio 0: no gate; no measured up: nothing to send
    assert attitude_prior_wanted(0.0, up_sigma, ratio=0.0)
    assert not attitude_prior_wanted(np.inf, float("nan"), ratio=0.6)


def test_gate_opens_only_after_a_stretch_of_weakly_held_keyframes():
    """vertical_gate_keyframes = 3: an isolated weak keyframe (the camera turned toward a row) sends nothing;
    the third weak keyframe in a row does, and a strong one closes the gate again."""
    history: list = []
    verdicts = [True, False, True, True, True, True, False, True]
    assert [weak_streak(history, w, 3) for w in verdicts] == [False, False, False, False, True, True, False, False]
    assert len(history) == 3
    assert weak_streak([], True, 1)                       # 1: this keyframe alone


def test_gate_settings_are_range_checked():
    with pytest.raises(ConfigError, match="vertical_gate_ratio"):
        TrackingParams(vertical_gate_ratio=-0.1)
    with pytest.raises(ConfigError, match="vertical_gate_far_baselines"):
        TrackingParams(vertical_gate_far_baselines=-1.0)
    with pytest.raises(ConfigError, match="vertical_gate_keyframes"):
        TrackingParams(vertical_gate_keyframes=0)
    assert TrackingParams().vertical_gate_ratio == 0.0    # default: no gate (and vertical_estimate off)


def test_sensor_gate_keeps_the_up_to_frames_the_enhancement_denoised_as_noisy():
    """tracking.vertical_min_sensor_sigma: the dim noisy presets' frames (the enhancement's sigma 14.6-16.1) send
    their up, clean preset frames (<= 9.21) and raw ones (0) do not; a run without the figure neither."""
    from canopy.frontend.vertical_gate import noisy_enough

    assert noisy_enough(None, 0.0) and noisy_enough(0.0, 0.0)          # 0: every keyframe
    assert noisy_enough(15.2, 11.0)
    assert not noisy_enough(9.21, 11.0) and not noisy_enough(0.0, 11.0) and not noisy_enough(None, 11.0)
    with pytest.raises(ConfigError, match="vertical_min_sensor_sigma"):
        TrackingParams(vertical_min_sensor_sigma=-1.0)
