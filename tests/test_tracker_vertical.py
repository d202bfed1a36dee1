"""The tracker's side of the attitude prior (``canopy.frontend.tracker_vertical``; tracking.vertical_estimate,
tracking.vertical_track_prior): the measured up of rendered post scenes and its reference, and the attitude term
in the motion-only refinement (``refine_pose``) pulling a noisy pose's tilt to the measured up."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend.attitude_prior import AttitudePoseTerm
from canopy.frontend.geometry import project_stereo, se3_exp, se3_inv
from canopy.frontend.params import TrackingParams
from canopy.frontend.pose import MotionPrior, refine_pose
from canopy.frontend.tracker_vertical import KeyframeVertical, SummedTerms, with_attitude
from shared.errors import ConfigError
from shared.types import StereoCalibration
from tests.test_vertical import K, angle_deg, camera, render

RENDER_CALIB = StereoCalibration(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], baseline=0.11, width=752, height=480)
CALIB = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)
UP = np.array([0.0, 0.0, 1.0])


def _pose(R_wc, c):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_wc, c
    return T


def test_keyframe_up_sets_the_reference_and_gates_the_next_frames():
    vert = KeyframeVertical(RENDER_CALIB, max_sigma_deg=2.0)
    R0, c0 = camera(-6.0, 0.0)
    assert vert.frame_term(render(R0, c0, seed=1), se3_inv(_pose(R0, c0)), 0) is None   # no reference yet
    up0, s0 = vert.measure(render(R0, c0, seed=1), _pose(R0, c0), 0)
    assert angle_deg(up0, R0.T @ UP) < 0.3 and 0 < s0 < 0.5
    assert angle_deg(vert.up_world, UP) < 0.3            # the world's up as the first keyframe's pose puts it
    # a later frame pitched 3 deg more, predicted 1 deg off: its term measures the frame's own up
    R1, c1 = camera(-3.0, 2.0)
    T_pred = _pose(camera(-4.0, 2.0)[0], c1)
    term = vert.frame_term(render(R1, c1, seed=2), se3_inv(T_pred), 7)
    assert angle_deg(term.up_cam[0], R1.T @ UP) < 0.3
    # the keyframe made from frame 7 reuses its measurement
    up7, _ = vert.measure(np.zeros((480, 752), np.uint8), T_pred, 7)
    np.testing.assert_array_equal(up7, term.up_cam[0])
    # an image without vertical structure: no measurement; a restart forgets the reference
    up_none, s_none = vert.measure(np.full((480, 752), 120, np.uint8), T_pred, 8)
    assert np.isnan(up_none).all() and np.isnan(s_none)
    vert.restart()
    assert vert.frame_term(render(R1, c1, seed=2), se3_inv(T_pred), 9) is None


def test_attitude_term_pins_the_refined_pose_tilt():
    """Few noisy stereo points leave a refined pose's tilt off; the exact up with a tight sigma brings it within
    0.002 deg, and summed with a (loose) motion prior it still does."""
    rng = np.random.default_rng(4)
    T_true = se3_exp(np.r_[0.05, -0.1, 0.02, 0.3, -0.1, 0.2])      # T_cam_world
    X = np.stack([rng.uniform(-3, 3, 25), rng.uniform(-1.5, 1.5, 25), rng.uniform(4, 12, 25)], 1)
    X = (se3_inv(T_true) @ np.c_[X, np.ones(25)].T).T[:, :3]       # points in front of the true camera
    meas = project_stereo(T_true, X, CALIB)[0] + rng.normal(0, 1.0, (25, 3))
    T0 = se3_exp(np.r_[0.01, -0.01, 0.005, 0.02, 0.0, 0.01]) @ T_true
    args = (X, meas, np.ones(25, bool), np.ones(25), CALIB, 2, 10, 5.991, 7.815)
    up_cam = T_true[:3, :3] @ UP
    tilt = lambda T: angle_deg(T[:3, :3] @ UP, up_cam)  # noqa: E731
    free = refine_pose(T0, *args)
    term = AttitudePoseTerm(up_cam, UP, np.radians(1e-3))
    pinned = refine_pose(T0, *args, extra=term)
    assert tilt(free.T_cam_world) > 0.01
    assert tilt(pinned.T_cam_world) < 0.002
    both = with_attitude(MotionPrior(T0, np.radians(5.0), 1.0), term)
    assert isinstance(both, SummedTerms)
    assert tilt(refine_pose(T0, *args, extra=both).T_cam_world) < 0.002
    assert with_attitude(None, term) is term and with_attitude(term, None) is term


def test_track_prior_needs_the_keyframe_measurement():
    with pytest.raises(ConfigError, match="vertical_track_prior"):
        TrackingParams(vertical_track_prior=True)
    TrackingParams(vertical_estimate=True, vertical_track_prior=True)
