"""The constant-velocity pose prior of motion-only refinement (canopy.frontend.pose.MotionPrior,
tracking.motion_prior_sigma_deg / _m): generated stereo scenes with exact ground truth."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.frontend import TrackingParams
from canopy.frontend.geometry import pose_information, project_stereo, rotation_angle, se3_exp, se3_inv, stereo_pose_jacobian
from canopy.frontend.pose import MotionPrior, refine_pose
from shared.errors import ConfigError
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=400.0, fy=400.0, cx=320.0, cy=240.0, baseline=0.12, width=640, height=480)


def world_points(rng, T_cw, n, zmin, zmax):
    z = rng.uniform(zmin, zmax, n)
    u = rng.uniform(20, CALIB.width - 20, n)
    v = rng.uniform(20, CALIB.height - 20, n)
    Pc = np.stack([(u - CALIB.cx) * z / CALIB.fx, (v - CALIB.cy) * z / CALIB.fy, z], axis=1)
    T_wc = se3_inv(T_cw)
    return Pc @ T_wc[:3, :3].T + T_wc[:3, 3]


def pose_error(T_a, T_b):
    d = se3_inv(T_a) @ T_b
    return np.degrees(rotation_angle(d[:3, :3])), float(np.linalg.norm(d[:3, 3]))


def test_prior_alone_returns_the_prediction():
    T_pred = se3_exp(np.array([0.01, -0.02, 0.005, 0.3, -0.1, 1.2]))
    prior = MotionPrior(T_pred, np.radians(0.1), 0.02)
    T = np.eye(4)
    for _ in range(4):  # Gauss-Newton on the prior alone: r - dx, Jacobian I
        H, g = prior.normal_equations(T, robust=True)
        T = se3_exp(np.linalg.solve(H, g)) @ T
    assert max(pose_error(T, T_pred)) < 1e-10


def test_refined_pose_is_the_stationary_point_of_measurements_plus_prior():
    """At the returned pose the gradient of the whole cost (points J^T W r plus prior Lambda r)
    vanishes while each part alone does not: the prior enters with its sign and weight."""
    rng = np.random.default_rng(3)
    T_true = se3_exp(np.array([0.02, 0.05, -0.01, 0.2, -0.1, 1.0]))
    X = world_points(rng, T_true, 40, 3.0, 15.0)
    meas, _ = project_stereo(T_true, X, CALIB)
    meas += rng.normal(0, 1.0, meas.shape)
    T_pred = se3_exp(np.array([0.0, 0.004, 0.0, 0.03, 0.0, 0.0])) @ T_true
    prior = MotionPrior(T_pred, np.radians(0.1), 0.02)
    sigma, everyone = np.ones(40), np.ones(40, bool)
    est = refine_pose(T_true, X, meas, everyone, sigma, CALIB, 1, 20, 1e9, 1e9, extra=prior)
    pred, Pc = project_stereo(est.T_cam_world, X, CALIB)
    J = stereo_pose_jacobian(Pc, CALIB).reshape(-1, 6)
    g_points = J.T @ (meas - pred).reshape(-1)
    _, g_prior = prior.normal_equations(est.T_cam_world, robust=False)
    assert np.linalg.norm(g_points + g_prior) < 1e-4 * np.linalg.norm(g_points)
    assert np.linalg.norm(g_points) > 1.0


def test_prior_cuts_rotation_error_on_few_near_noisy_points():
    """The issue-9 case in miniature: 25 near points (3-12 m) at 1.5 px noise; a prediction off
    the truth by a car's per-frame change of motion (0.05 deg, 1 cm). Over 40 draws the prior
    (0.1 deg, 2 cm) lowers the rms rotation and translation errors of the refined pose."""
    rng = np.random.default_rng(17)
    err_off, err_on = [], []
    for _ in range(40):
        T_true = se3_exp(np.concatenate([rng.normal(0, 0.02, 3), rng.normal(0, 0.5, 3)]))
        X = world_points(rng, T_true, 25, 3.0, 12.0)
        meas, _ = project_stereo(T_true, X, CALIB)
        meas += rng.normal(0, 1.5, meas.shape)
        accel = np.concatenate([rng.normal(0, np.radians(0.05) / np.sqrt(3), 3), rng.normal(0, 0.01 / np.sqrt(3), 3)])
        T_pred = se3_exp(accel) @ T_true
        args = (X, meas, np.ones(25, bool), np.ones(25), CALIB, 4, 10, 5.991, 7.815)
        err_off.append(pose_error(T_true, refine_pose(T_pred, *args).T_cam_world))
        prior = MotionPrior(T_pred, np.radians(0.1), 0.02)
        err_on.append(pose_error(T_true, refine_pose(T_pred, *args, extra=prior).T_cam_world))
    rms_off, rms_on = np.sqrt(np.mean(np.square(err_off), axis=0)), np.sqrt(np.mean(np.square(err_on), axis=0))
    assert rms_on[0] < 0.7 * rms_off[0] and rms_on[1] < 0.8 * rms_off[1]


def test_prior_barely_moves_a_well_measured_pose():
    """Information weighting: 300 points at 0.3 px, a prediction 1 deg / 20 cm off the truth
    (a wrong motion model): the pose stays within 0.1 deg / 2 cm of the truth."""
    rng = np.random.default_rng(5)
    T_true = se3_exp(np.array([0.01, 0.03, 0.0, 0.1, 0.0, 1.1]))
    X = world_points(rng, T_true, 300, 3.0, 30.0)
    meas, _ = project_stereo(T_true, X, CALIB)
    meas += rng.normal(0, 0.3, meas.shape)
    T_pred = se3_exp(np.array([0.0, np.radians(1.0), 0.0, 0.2, 0.0, 0.0])) @ T_true
    prior = MotionPrior(T_pred, np.radians(0.1), 0.02)
    est = refine_pose(T_pred, X, meas, np.ones(300, bool), np.ones(300), CALIB, 4, 10, 5.991, 7.815, extra=prior)
    deg, m = pose_error(T_true, est.T_cam_world)
    assert deg < 0.1 and m < 0.02
    assert est.inliers.mean() > 0.9
    _, Pc = project_stereo(est.T_cam_world, X[est.inliers], CALIB)
    n = int(est.inliers.sum())  # the pose's information is the measurements' only (AGRI Eq. 6's entropy)
    np.testing.assert_allclose(est.information, pose_information(stereo_pose_jacobian(Pc, CALIB), np.ones(n),
                                                                 np.ones(n)), rtol=1e-9)


def test_negative_sigma_is_rejected_by_name():
    with pytest.raises(ConfigError, match="motion_prior_sigma_deg"):
        TrackingParams(motion_prior_sigma_deg=-0.1)
