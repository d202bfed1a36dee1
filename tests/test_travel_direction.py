"""The rig's direction of travel as a prior of motion-only refinement (canopy.frontend.travel_direction,
tracking.travel_direction_sigma_deg): a car's camera driven along generated arcs with exact ground truth."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.frontend import TrackingParams
from canopy.frontend.geometry import project_stereo, rotation_angle, se3_exp, se3_inv, so3_exp
from canopy.frontend.pose import refine_pose
from canopy.frontend.travel_direction import (TravelDirection, TravelDirectionTerm, texture_gate_open,
                                              travel_direction_term)
from shared.errors import ConfigError
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=700.0, fy=700.0, cx=600.0, cy=185.0, baseline=0.54, width=1200, height=370)
# the camera on the car: yawed 0.3 deg and pitched 1.2 deg against the direction of travel (KITTI's
# cam0 measures about -2 / -21 mrad in its ground truth)
MOUNT = so3_exp(np.array([np.radians(1.2), np.radians(0.3), 0.0]))


def car_track(n: int, step_m: float, yaw_rates_deg: np.ndarray) -> list[np.ndarray]:
    """T_world_cam of a camera on a car that drives ``n`` frames along circular arcs (the car's x-z plane,
    y down), turning by ``yaw_rates_deg[k]`` in frame k; the car's heading is its direction of travel."""
    poses, pos, heading = [], np.zeros(3), 0.0
    for k in range(n):
        R_car = so3_exp(np.array([0.0, heading, 0.0]))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R_car @ MOUNT.T, pos
        poses.append(T)
        turn = np.radians(yaw_rates_deg[k % len(yaw_rates_deg)])
        # the chord of an arc of angle `turn` leaves at half the turn (Scaramuzza 2011, Eq. 3)
        chord = so3_exp(np.array([0.0, heading + turn / 2, 0.0])) @ np.array([0.0, 0.0, 1.0])
        pos = pos + step_m * chord
        heading += turn
    return poses


def test_learns_the_mount_and_predicts_the_next_chord_on_arcs():
    poses = car_track(30, 1.2, np.array([0.0, 0.4, 1.5, -0.8, 0.1]))
    travel = TravelDirection(window=20, min_steps=5, min_step_m=0.05)
    for a, b in zip(poses[:-2], poses[1:-1]):
        travel.add(se3_inv(a) @ b)
    forward_cam = MOUNT @ np.array([0.0, 0.0, 1.0])   # the car's forward axis in the camera frame
    np.testing.assert_allclose(travel.forward(), forward_cam, atol=1e-9)
    last, nxt = poses[-2], poses[-1]
    T_last_cur = se3_inv(last) @ nxt
    chord = T_last_cur[:3, 3] / np.linalg.norm(T_last_cur[:3, 3])
    np.testing.assert_allclose(travel.expected_chord(T_last_cur), chord, atol=1e-9)


def test_a_reversing_rig_keeps_its_line_of_travel():
    """Backing up: the steps point the other way along the same line; the learned direction stays on it."""
    poses = car_track(12, 1.0, np.array([0.2]))
    travel = TravelDirection(window=20, min_steps=5, min_step_m=0.05)
    steps = [se3_inv(a) @ b for a, b in zip(poses[:-1], poses[1:])]
    for step in steps[:4] + [se3_inv(s) for s in steps[4:9]]:    # 4 forward, then 5 in reverse
        travel.add(step)
    forward_cam = MOUNT @ np.array([0.0, 0.0, 1.0])
    assert abs(float(travel.forward() @ forward_cam)) > 1 - 1e-9


def test_unknown_until_enough_moving_steps():
    travel = TravelDirection(window=10, min_steps=3, min_step_m=0.05)
    still = np.eye(4)
    still[:3, 3] = [0.001, 0.0, 0.01]
    for _ in range(5):
        travel.add(still)              # standing still: no direction
    assert travel.forward() is None
    step = np.eye(4)
    step[2, 3] = 1.0
    for _ in range(3):
        travel.add(step)
    np.testing.assert_allclose(travel.forward(), [0.0, 0.0, 1.0])
    assert travel_direction_term(travel, np.eye(4), still, 0.1) is None   # a still prediction: no term


def test_jacobian_matches_finite_differences():
    T_last_cw = se3_exp(np.array([0.01, -0.02, 0.003, 0.4, 0.1, -2.0]))
    term = TravelDirectionTerm(T_last_cw, np.array([0.01, -0.02, 1.0]), np.radians(0.2), 1.2)
    T = se3_exp(np.array([0.0, 0.01, 0.0, 0.05, 0.02, -1.1])) @ T_last_cw
    H, g = term.normal_equations(T, robust=False)
    r0 = term.residual(T)
    J = np.zeros((2, 6))
    for i in range(6):
        dx = np.zeros(6)
        dx[i] = 1e-7
        J[:, i] = (term.residual(se3_exp(dx) @ T) - r0) / 1e-7
    np.testing.assert_allclose(H, term.weight * J.T @ J, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(g, -term.weight * J.T @ r0, rtol=1e-5, atol=1e-3)


def test_prior_cuts_the_sideways_error_of_a_pose_held_by_near_points():
    """The hazy KITTI frame in miniature: 30 points 4-15 m ahead at 1.5 px noise hold yaw and sideways
    translation only together. Over 40 draws along arcs, the prior (0.15 deg) learned from the previous
    steps halves the rms sideways error of the step and lowers the rotation error; the step's length
    (the scale) it leaves alone."""
    rng = np.random.default_rng(11)
    poses = car_track(12, 1.2, np.array([0.3, 0.6, -0.2]))
    travel = TravelDirection(window=20, min_steps=5, min_step_m=0.05)
    for a, b in zip(poses[:-2], poses[1:-1]):
        travel.add(se3_inv(a) @ b)
    T_last_wc, T_true_wc = poses[-2], poses[-1]
    T_true = se3_inv(T_true_wc)
    velocity = se3_inv(poses[-3]) @ T_last_wc    # the constant-velocity model's prediction
    T_pred = se3_inv(T_last_wc @ velocity)
    chord = se3_inv(T_last_wc) @ T_true_wc
    chord = chord[:3, 3] / np.linalg.norm(chord[:3, 3])
    side_off, side_on, rot_off, rot_on, len_off, len_on = [], [], [], [], [], []
    for _ in range(40):
        z = rng.uniform(4.0, 15.0, 30)
        u, v = rng.uniform(20, CALIB.width - 20, 30), rng.uniform(20, CALIB.height - 20, 30)
        Pc = np.stack([(u - CALIB.cx) * z / CALIB.fx, (v - CALIB.cy) * z / CALIB.fy, z], axis=1)
        X = Pc @ T_true_wc[:3, :3].T + T_true_wc[:3, 3]
        meas, _ = project_stereo(T_true, X, CALIB)
        meas += rng.normal(0, 1.5, meas.shape)
        args = (X, meas, np.ones(30, bool), np.ones(30), CALIB, 4, 10, 5.991, 7.815)
        term = travel_direction_term(travel, T_last_wc, velocity, 0.15)
        for extra, side, rot, length in ((None, side_off, rot_off, len_off), (term, side_on, rot_on, len_on)):
            T = refine_pose(T_pred, *args, extra=extra).T_cam_world
            step = (se3_inv(T_last_wc) @ se3_inv(T))[:3, 3]
            side.append(np.linalg.norm(step - chord * (step @ chord)))
            rot.append(np.degrees(rotation_angle((T @ T_true_wc)[:3, :3])))
            length.append(abs(np.linalg.norm(step) - 1.2))
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
    assert rms(side_on) < 0.5 * rms(side_off)
    assert rms(rot_on) < rms(rot_off)
    assert rms(len_on) < 1.2 * rms(len_off)


def test_texture_gate_admits_hazy_raw_frames_only():
    """travel_direction_max_texture: haze flattens the texture excess (KITTI 0.2-1.9 grey levels at beta
    0.03-0.06, clean 3.4-4.5); a frame the enhancement changed has no robust sigma and stays out."""
    assert texture_gate_open(None, None, 0.0)                 # 0: every frame
    assert texture_gate_open(2.0, 3.2, 2.15)                  # hazy: 1.2 grey levels of texture
    assert not texture_gate_open(1.8, 5.8, 2.15)              # clean KITTI: 4.0
    assert not texture_gate_open(None, 3.0, 2.15)             # enhanced frame


def test_bad_settings_are_rejected_by_name():
    with pytest.raises(ConfigError, match="travel_direction_sigma_deg"):
        TrackingParams(travel_direction_sigma_deg=-0.1)
    with pytest.raises(ConfigError, match="travel_direction_min_steps"):
        TrackingParams(travel_direction_window=3, travel_direction_min_steps=5)
    with pytest.raises(ConfigError, match="travel_direction_max_texture"):
        TrackingParams(travel_direction_max_texture=-1.0)
