"""Is a frame's pose trustworthy? Divergence checks and lost reasons of the tracker (issue 9).

A tracker that accepts every pose it computes writes wild jumps into the trajectory when the
images stop carrying the scene (darkness, haze, noise). ``judge_pose`` checks an estimate
against what tracking must show (enough inliers, a sane inlier fraction, a motion consistent
with the constant-velocity model) and returns a lost reason, "" when the pose is trusted.
``LOST_REASONS`` lists every reason the tracker can give (``TrackingResult.lost_reason``).

``image_noise_sigma`` estimates the grey-level noise of an image cheaply (Immerkaer, "Fast
noise variance estimation", CVIU 1996: the Laplacian-difference mask cancels image structure
up to second order; mean |response| * sqrt(pi/2) / 6 is the noise sigma), on every second
pixel of every second row so that the noise is not averaged away. The ORB extractor raises its
FAST threshold to ``fast_noise_factor`` x that sigma (default 3), so that on noisy frames corners come from
the signal rather than from the noise; clean frames (sigma of 1-2 grey levels) keep the
configured threshold (the estimate also sees fine texture: 2-6 grey levels on clean KITTI, EuRoC
and generated frames, below 20 / 3).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.frontend.geometry import rotation_angle, se3_inv

# reasons a frame has no tracked pose (the first four from the tracker's own checks)
LOST_TOO_FEW_STEREO = "too_few_stereo_points"      # (re)initialisation needs min_init_points
LOST_TOO_FEW_MATCHES = "too_few_matches"            # no RANSAC pose: too few 3D-2D matches
LOST_TOO_FEW_INLIERS = "too_few_inliers"            # the refined pose keeps < min_inliers
LOST_LOW_INLIER_FRACTION = "low_inlier_fraction"    # most matches disagree with the pose
LOST_INCONSISTENT_MOTION = "inconsistent_motion"    # the pose jumps away from the motion model
LOST_REASONS = (LOST_TOO_FEW_STEREO, LOST_TOO_FEW_MATCHES, LOST_TOO_FEW_INLIERS, LOST_LOW_INLIER_FRACTION,
                LOST_INCONSISTENT_MOTION)

_LAPLACE_DIFF = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def image_noise_sigma(image: np.ndarray) -> float:
    """Noise sigma (grey levels) of a grey image, Immerkaer 1996 on a 2x decimated copy."""
    img = np.asarray(image)
    if img.ndim != 2 or img.shape[0] < 8 or img.shape[1] < 8:
        return 0.0
    sub = np.ascontiguousarray(img[::2, ::2], np.float32)
    resp = cv2.filter2D(sub, cv2.CV_32F, _LAPLACE_DIFF, borderType=cv2.BORDER_REPLICATE)[1:-1, 1:-1]
    return float(np.sqrt(np.pi / 2.0) * np.mean(np.abs(resp)) / 6.0)


def motion_deviation(T_cw: np.ndarray, T_pred_cw: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) between an estimated and a predicted camera pose."""
    D = se3_inv(T_pred_cw) @ T_cw
    dt = float(np.linalg.norm(se3_inv(T_cw)[:3, 3] - se3_inv(T_pred_cw)[:3, 3]))
    return dt, float(np.degrees(rotation_angle(D[:3, :3])))


def judge_pose(n_support: int, n_matches: int, T_cw: np.ndarray, T_pred_cw: np.ndarray, params,
               check_motion: bool) -> str:
    """Lost reason of an estimated pose ("" = trusted). ``check_motion``: the motion model is
    valid (not right after a (re)initialisation or a gap)."""
    if n_support < params.min_inliers:
        return LOST_TOO_FEW_INLIERS
    if n_matches > 0 and n_support < params.min_inlier_fraction * n_matches:
        return LOST_LOW_INLIER_FRACTION
    if check_motion:
        dt, dr = motion_deviation(T_cw, T_pred_cw)
        if dt > params.max_motion_deviation_m or dr > params.max_motion_deviation_deg:
            return LOST_INCONSISTENT_MOTION
    return ""


def ransac_departs(T_cw: np.ndarray, T_pred_cw: np.ndarray, params) -> bool:
    """Does a RANSAC pose depart from the constant-velocity prediction by more than the motion
    model can be wrong (``ransac_max_deviation_deg`` / ``_m``, either one; 0 = that test off)?

    With 40-80 stage-1 matches of which half are right (dark, hazy, noisy frames) EPnP's best
    minimal set can be a yaw + sideways shift that keeps the near points (all at ~10 m) in place:
    a rotation by theta moves them as a translation of z * theta does. The local-map search then
    looks in a small window around that pose and confirms it. The prediction errs only by the
    change of the vehicle's motion over one frame plus the last frame's error."""
    max_deg, max_m = params.ransac_max_deviation_deg, params.ransac_max_deviation_m
    if max_deg <= 0 and max_m <= 0:
        return False
    dt, dr = motion_deviation(T_cw, T_pred_cw)
    return (max_deg > 0 and dr > max_deg) or (max_m > 0 and dt > max_m)
