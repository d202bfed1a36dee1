"""Send a keyframe's measured up only where its own points hold its pitch and roll weakly (issue 9).

docs/notes/s25-attitude.md measured the pitch/roll prior of ``canopy.backend.attitude_prior`` paying on every
hazy cell (the haze hides the far trees: a few dozen far inliers a frame) and costing every noisy haze-free
cell, where ~240 far keypoints a frame pin the rotation already and the prior only adds its own noise
(even the generator's exact up costs day-loop g0.15-b0-high seed 0 7.5 -> 12.9 mm). The gate compares the two
information sources the BA would fuse, per keyframe:

* vision's: the standard deviation of the keyframe's rotation about the two axes perpendicular to the up
  (pitch and roll; yaw is what a vertical cannot see) that its **far** pose inliers alone give (beyond
  tracking.vertical_gate_far_baselines, default 40 baselines: ORB-SLAM's ThDepth close/far split), the rotation
  block of (J^T Sigma^-1 J)^-1 marginalised over the translation (the Cramér-Rao bound the tracker's
  ``_measurements_weak`` computes for the motion prior's gate; J the stereo projection's pose Jacobian, AGRI
  Eq. 8, bearing-only rows for the points without a right-image column). Far points, not all inliers: a far
  point's bearing barely moves with the camera, so it stays matched to the same landmark for many keyframes
  and ties the attitude to the old map (what makes the haze-free cells drift-free, s21-dimpitch, s24-dimhaze:
  4 % of the inliers beyond 10 m with haze, 20 % without); the near points' rotation information is re-anchored
  on new landmarks every few keyframes, so it bounds the frame's noise, not the drift. Measured per keyframe
  (s26-gate): all inliers give 0.025-0.03 deg on the haze-free and 0.03-0.04 deg on the hazy cells (no
  margin); the far ones 0.2-0.4 x the up's sigma without haze and 0.6-1.1 x with it.
* the measured up's sigma (``canopy.lines.vertical``; honest on the presets, s25-vertical).

The prior joins when the far points' sigma is at least ``ratio`` x the up's sigma. Both are angles and the far
split is in baselines, so the test is scale-free: it does not depend on the scene's size or the number of
pixels, only on how much each source knows about the attitude. ``ratio`` is measured in docs/notes/s26-gate.md.
"""
from __future__ import annotations

import os
import sys

import numpy as np

from canopy.frontend.geometry import pose_information, stereo_pose_jacobian

_DEBUG = bool(os.environ.get("CANOPY_VERTICAL_GATE_DEBUG"))  # print each keyframe's gate inputs


def attitude_std_deg(Pc: np.ndarray, sigma_px: np.ndarray, has_right: np.ndarray, calib,
                     up_cam: np.ndarray) -> float:
    """The largest standard deviation (deg) of the camera's rotation about an axis perpendicular to
    ``up_cam`` that stereo / bearing-only measurements of the camera-frame points ``Pc`` (N,3) with pixel
    sigmas ``sigma_px`` give, translation and yaw free (inf when they do not fix it: too few points)."""
    front = Pc[:, 2] > 1e-6
    if front.sum() < 3:
        return float("inf")
    info = pose_information(stereo_pose_jacobian(Pc[front], calib), np.asarray(sigma_px, float)[front],
                            np.asarray(has_right, float)[front])
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return float("inf")
    if not np.all(np.isfinite(cov)):
        return float("inf")
    u = np.asarray(up_cam, float) / np.linalg.norm(up_cam)
    # two axes perpendicular to the up: the rotations a vertical measures (pitch, roll)
    a = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    B = np.stack([a, np.cross(u, a)], axis=1)
    cov_att = B.T @ cov[:3, :3] @ B
    return float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov_att).max(), 0.0))))


def attitude_prior_wanted(vision_std_deg: float, up_sigma_deg: float, ratio: float) -> bool:
    """True when the measured up (sigma ``up_sigma_deg``) would add to what the points know (vision's own
    pitch/roll sigma ``vision_std_deg``): vision's sigma >= ``ratio`` x the up's. ``ratio`` <= 0: always
    (the gate off); a NaN up: never."""
    if not np.isfinite(up_sigma_deg):
        return False
    if ratio <= 0:
        return True
    return bool(vision_std_deg >= ratio * up_sigma_deg)


def keyframe_points(tracker, feats, stereo, T_wc: np.ndarray, matched_ids: np.ndarray):
    """The keyframe's pose inliers as the gate sees them: (camera-frame points (N,3), pixel sigmas, has a
    right-image measurement). Tracked keyframes: the landmarks its frame matched (their map positions, the
    tracker's ``_last_matched``); a segment's first keyframe: its own stereo points."""
    T_cw = np.linalg.inv(T_wc)
    f_idx = np.flatnonzero(matched_ids >= 0)
    X, _, ids = tracker._last_matched
    if len(f_idx) and len(ids):
        order = np.argsort(ids)
        pos = np.searchsorted(ids[order], matched_ids[f_idx])
        pos = np.minimum(pos, len(ids) - 1)
        ok = ids[order][pos] == matched_ids[f_idx]
        f_idx, Xw = f_idx[ok], X[order][pos[ok]]
        Pc = Xw @ T_cw[:3, :3].T + T_cw[:3, 3]
    else:   # (re)initialisation: the frame's stereo points
        f_idx = np.flatnonzero(tracker._landmark_candidates(stereo))
        Pc = (T_cw[:3, :3] @ tracker._stereo_points_world(feats, stereo, T_wc, f_idx).T).T + T_cw[:3, 3]
    has_right = tracker._keyframe_u_right(stereo)[f_idx] >= 0
    return Pc, tracker._sigma(feats.octave[f_idx]), has_right


def weak_streak(history: list, weak: bool, keyframes: int) -> bool:
    """Appends this keyframe's verdict to ``history`` (the map segment's, kept to ``keyframes`` entries) and
    tells whether the last ``keyframes`` keyframes, this one included, were all weakly held. Haze hides the far
    trees for a stretch of the sequence; a single keyframe without far inliers (the camera turned toward a
    row) is not haze, and on the haze-free cells one prior keyframe alone moved an ATE by 40 % (s26-gate)."""
    history.append(bool(weak))
    del history[:-keyframes]
    return len(history) == keyframes and all(history)


def gate_keyframe_up(tracker, feats, stereo, T_wc, matched_ids, up_cam, up_sigma_deg, history: list):
    """tracking.vertical_gate_ratio: (up_cam, sigma) unchanged where the prior is wanted, NaN otherwise.
    ``history``: the map segment's verdicts (``KeyframeVertical.gate_history``, cleared on a restart)."""
    p = tracker.params
    if p.vertical_gate_ratio <= 0 and not _DEBUG:
        return up_cam, up_sigma_deg
    if not np.isfinite(up_sigma_deg):
        weak_streak(history, False, p.vertical_gate_keyframes)
        return up_cam, up_sigma_deg
    Pc, sigma, has_right = keyframe_points(tracker, feats, stereo, T_wc, matched_ids)
    far = Pc[:, 2] > p.vertical_gate_far_baselines * tracker.calib.baseline
    vision = attitude_std_deg(Pc[far], sigma[far], has_right[far], tracker.calib, up_cam)
    weak = attitude_prior_wanted(vision, up_sigma_deg, p.vertical_gate_ratio)
    wanted = weak_streak(history, weak, p.vertical_gate_keyframes)
    if _DEBUG:
        print(f"VGATE n {len(Pc)} far {int(far.sum())} vision {vision:.5f} up {up_sigma_deg:.4f} weak {int(weak)} "
              f"open {int(wanted)}", file=sys.stderr, flush=True)
    if wanted:
        return up_cam, up_sigma_deg
    return np.full(3, np.nan), float("nan")


def noisy_enough(sensor_sigma: float | None, min_sensor_sigma: float) -> bool:
    """tracking.vertical_min_sensor_sigma: True when a keyframe may measure and send its up. 0: every keyframe;
    > 0: only frames the enhancement denoised at a noise sigma (its own figure, ``info["noise_sigma"]``) of at
    least this: the dim noisy presets read 14.6-16.1, every clean preset frame <= 9.21, raw frames 0
    (docs/notes/s20-dimsigma.md). Without the figure (a caller that does not hand it over): no."""
    if min_sensor_sigma <= 0:
        return True
    return sensor_sigma is not None and float(sensor_sigma) >= min_sensor_sigma
