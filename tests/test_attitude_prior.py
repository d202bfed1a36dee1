"""The attitude prior of local BA (``canopy.backend.attitude_prior``, mapping.attitude_prior): its Jacobian, its
pull on the keyframes' tilt in the Schur solver, GTSAM's AttitudeFactor with the same cost, the segment's
reference, and the keyframe message's up field."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest

import canopy.backend.stereo_ba as sb
from canopy.backend.attitude_prior import AttitudePriors, AttitudeStore, attitude_factors, attitude_residuals, \
    tangent_basis
from canopy.backend.params import MappingParams
from canopy.frontend.geometry import project_stereo, se3_exp, se3_inv
from canopy.frontend.params import TrackingParams
from protocol.codec import decode, encode
from protocol.messages import KeyframeData
from shared.errors import ConfigError
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)
UP_WORLD = np.array([0.0, 0.0, 1.0])


def _tilt_deg(T_cw: np.ndarray, up_cam: np.ndarray) -> np.ndarray:
    """Angle (deg) between each pose's predicted up R_cw g and the camera-frame up ``up_cam``."""
    pred = np.einsum("mij,j->mi", T_cw[:, :3, :3], UP_WORLD)
    return np.degrees(np.arccos(np.clip(np.einsum("mi,mi->m", pred, up_cam), -1, 1)))


def test_residual_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    R = np.stack([se3_exp(np.r_[0.4 * rng.standard_normal(3), 0, 0, 0])[:3, :3] for _ in range(5)])
    u = np.einsum("mij,j->mi", R, UP_WORLD) + 0.03 * rng.standard_normal((5, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    B = tangent_basis(u)
    np.testing.assert_allclose(np.einsum("mik,mi->mk", B, u), 0, atol=1e-12)
    r, J = attitude_residuals(R, u, UP_WORLD, B)
    # |r| is the angle between the predicted and the measured up to first order
    ang = np.radians(_tilt_deg(np.concatenate([R, np.zeros((5, 3, 1))], axis=2), u))
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), ang, rtol=2e-3)
    eps = 1e-6
    for a in range(3):
        w = np.zeros(6)
        w[a] = eps
        rp, _ = attitude_residuals(np.stack([se3_exp(w)[:3, :3] @ Ri for Ri in R]), u, UP_WORLD, B)
        np.testing.assert_allclose((rp - r) / eps, J[:, :, a], atol=1e-5)


def _window(rng, n_poses=5, n_local=3, n_points=120, pixel_noise=1.5):
    """Poses 1 m apart along x, tilted a little, seeing points 3-15 m ahead; noisy pixels."""
    T = np.stack([se3_exp(np.r_[0.03 * rng.standard_normal(3), -1.0 * k, 0.05 * rng.standard_normal(2)])
                  for k in range(n_poses)])
    X = np.stack([rng.uniform(-4, 4, n_points) + 2, rng.uniform(-2, 2, n_points), rng.uniform(3, 15, n_points)], 1)
    pose = np.repeat(np.arange(n_poses), n_points)
    point = np.tile(np.arange(n_points), n_poses)
    order = np.argsort(point, kind="stable")
    pose, point = pose[order], point[order]
    meas = np.stack([project_stereo(T[k], X[p][None], CALIB)[0][0] for k, p in zip(pose, point)])
    E = len(pose)
    edges = sb.StereoEdges(pose, point, meas + rng.normal(0, pixel_noise, meas.shape), np.ones(E, bool),
                           np.ones(E), np.full(E, 2.45))
    return T, X, edges, n_local


def test_prior_pins_the_local_poses_tilt_to_the_measured_up():
    """Noisy pixels leave the local poses' tilt off by a few hundredths of a degree; the exact up with a
    tight sigma brings every local pose's up within 0.002 deg of the truth, and its cost enters LM."""
    rng = np.random.default_rng(7)
    T_true, X_true, edges, n_local = _window(rng)
    T0 = T_true.copy()
    for k in range(n_local):   # start the local poses off in rotation
        T0[k] = se3_exp(np.r_[0.01 * rng.standard_normal(3), 0.02 * rng.standard_normal(3)]) @ T_true[k]
    up_true = np.einsum("mij,j->mi", T_true[:, :3, :3], UP_WORLD)
    T_free, _, _ = sb.bundle_adjust_points(T0, n_local, X_true, edges, CALIB, 20)
    tilt_free = _tilt_deg(T_free[:n_local], up_true[:n_local])
    pri = AttitudePriors(pose=np.arange(n_local), up_cam=up_true[:n_local], sigma=np.full(n_local, np.radians(1e-3)),
                         up_world=UP_WORLD)
    T_pri, _, _ = sb.bundle_adjust_points(T0, n_local, X_true, edges, CALIB, 20, attitude=pri)
    tilt_pri = _tilt_deg(T_pri[:n_local], up_true[:n_local])
    assert tilt_free.max() > 0.01, tilt_free
    assert tilt_pri.max() < 0.002, tilt_pri
    # fixed poses stay
    np.testing.assert_array_equal(T_pri[n_local:], T0[n_local:])


def test_gtsam_attitude_factor_has_the_same_cost():
    """GTSAM's AttitudeFactor on T_world_cam (``attitude_factors``: the GTSAM path of local BA) and the Schur
    solver's term give the same cost on tilted poses."""
    rng = np.random.default_rng(5)
    for _ in range(4):
        T_wc = se3_exp(np.r_[0.3 * rng.standard_normal(3), rng.standard_normal(3)])
        u = T_wc[:3, :3].T @ UP_WORLD + 0.02 * rng.standard_normal(3)
        u /= np.linalg.norm(u)
        pri = AttitudePriors(np.array([0]), u[None], np.array([np.radians(0.5)]), UP_WORLD)
        key = gtsam.symbol("x", 0)
        f = attitude_factors([key], pri)[0]
        v = gtsam.Values()
        v.insert(key, gtsam.Pose3(T_wc))
        assert f.error(v) == pytest.approx(pri.cost(se3_inv(T_wc)[None]), rel=1e-3)


def test_store_builds_each_segments_reference_and_ignores_missing_ups():
    store = AttitudeStore(reference_keyframes=2)
    T0 = se3_exp(np.r_[0.1, 0.0, 0.0, 0, 0, 0])
    up0 = T0[:3, :3].T @ UP_WORLD
    assert not store.add(0, 0, T0, np.full(3, np.nan), 0.2)   # no measurement
    assert store.priors([0]) is None
    assert store.add(1, 0, T0, up0, 0.2)
    np.testing.assert_allclose(store.reference(0), UP_WORLD, atol=1e-12)
    # a second keyframe 1 deg off joins the reference with the same weight; a third does not
    up1 = se3_exp(np.r_[np.radians(1.0), 0.0, 0.0, 0, 0, 0])[:3, :3] @ UP_WORLD
    store.add(2, 0, np.eye(4), up1, 0.2)
    store.add(3, 0, np.eye(4), up1, 0.2)
    tilt = np.degrees(np.arccos(store.reference(0) @ UP_WORLD))
    assert tilt == pytest.approx(0.5, abs=1e-6)
    # a new map segment has its own reference
    store.add(4, 1, np.eye(4), np.array([0.0, -1.0, 0.0]), 0.2)
    np.testing.assert_allclose(store.reference(1), [0.0, -1.0, 0.0])
    pri = store.priors([3, 9, 1])
    np.testing.assert_array_equal(pri.pose, [0, 2])
    np.testing.assert_allclose(pri.sigma, np.radians(0.2))


def test_keyframe_message_carries_the_up_and_settings_are_checked():
    kf = KeyframeData(index=3, timestamp=0.1, T_world_cam=np.eye(4), uv=np.zeros((0, 2), np.float32),
                      u_right=np.zeros(0, np.float32), depth=np.zeros(0, np.float32),
                      descriptors=np.zeros((0, 32), np.uint8), octave=np.zeros(0, np.int32),
                      landmark_ids=np.zeros(0, np.int64), new_landmark_ids=np.zeros(0, np.int64))
    assert np.isnan(kf.up_cam).all() and np.isnan(kf.up_sigma_deg)
    kf.up_cam, kf.up_sigma_deg = np.array([0.0, -0.99, 0.1]), 0.3
    back = decode(encode(kf))
    np.testing.assert_array_equal(back.up_cam, kf.up_cam)
    assert back.up_sigma_deg == 0.3
    with pytest.raises(ConfigError, match="attitude_reference_keyframes"):
        MappingParams(attitude_reference_keyframes=0)
    with pytest.raises(ConfigError, match="vertical_max_sigma_deg"):
        TrackingParams(vertical_max_sigma_deg=0.0)
