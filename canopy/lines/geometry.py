"""Line reprojection error of AGRI Eq. 10 and its analytic Jacobians.

The observation of a segment with endpoints p, q (pixels) is its infinite line
``l = (p~ x q~) / |(l0, l1)|`` (homogeneous p~ = (u, v, 1)), normalised so that ``l . x~``
is the signed pixel distance of x from the line. The residual of a 3D segment (A_w, B_w)
seen from pose T_cam_world is ``e = (l . pi~(T A_w), l . pi~(T B_w))`` with pi the left
projection of Eq. 8.

Pose perturbations follow ``canopy.frontend.geometry``: xi = (omega, v), ``T <- exp(xi) @ T``.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.geometry import stereo_pose_jacobian, transform
from shared.types import StereoCalibration


def line_coefficients(segs: np.ndarray) -> np.ndarray:
    """(N,3) normalised infinite lines through (N,4) segments (x1, y1, x2, y2)."""
    s = np.asarray(segs, np.float64).reshape(-1, 4)
    p = np.column_stack([s[:, 0], s[:, 1], np.ones(len(s))])
    q = np.column_stack([s[:, 2], s[:, 3], np.ones(len(s))])
    l = np.cross(p, q)
    n = np.hypot(l[:, 0], l[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return l / n[:, None]


def _point_terms(Pc: np.ndarray, lines: np.ndarray, calib: StereoCalibration):
    """Signed distances (N,) and their gradient w.r.t. the camera-frame point (N,3)."""
    x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
    iz = 1.0 / z
    u = calib.fx * x * iz + calib.cx
    v = calib.fy * y * iz + calib.cy
    d = lines[:, 0] * u + lines[:, 1] * v + lines[:, 2]
    a, b = lines[:, 0] * calib.fx * iz, lines[:, 1] * calib.fy * iz
    g = np.column_stack([a, b, -(a * x + b * y) * iz])
    return d, g


def line_residuals(T_cw: np.ndarray, A_w: np.ndarray, B_w: np.ndarray, lines: np.ndarray,
                   calib: StereoCalibration, jacobians: bool = False):
    """Batched Eq. 10 for N segments: residuals (N,2) in pixels.

    With ``jacobians``: also J_pose (N,2,6) w.r.t. xi, J_A (N,3) = d e_0 / d A_w and
    J_B (N,3) = d e_1 / d B_w (e_0 does not depend on B_w, nor e_1 on A_w).
    """
    A_w = np.asarray(A_w, float).reshape(-1, 3)
    B_w = np.asarray(B_w, float).reshape(-1, 3)
    lines = np.asarray(lines, float).reshape(-1, 3)
    PA, PB = transform(T_cw, A_w), transform(T_cw, B_w)
    dA, gA = _point_terms(PA, lines, calib)
    dB, gB = _point_terms(PB, lines, calib)
    e = np.column_stack([dA, dB])
    if not jacobians:
        return e
    R = T_cw[:3, :3]
    l2 = lines[:, :2]
    J_pose = np.stack([np.einsum("nk,nkj->nj", l2, stereo_pose_jacobian(PA, calib)[:, :2, :]),
                       np.einsum("nk,nkj->nj", l2, stereo_pose_jacobian(PB, calib)[:, :2, :])], axis=1)
    return e, J_pose, gA @ R, gB @ R


def line_reprojection_error(T_cw: np.ndarray, A_w: np.ndarray, B_w: np.ndarray, line_coeffs_l: np.ndarray,
                            calib: StereoCalibration) -> np.ndarray:
    """AGRI Eq. 10 for one segment: (2,) distances of the projected endpoints to the line."""
    return line_residuals(T_cw, A_w, B_w, line_coeffs_l, calib)[0]


def line_reprojection_jacobians(T_cw: np.ndarray, A_w: np.ndarray, B_w: np.ndarray, line_coeffs_l: np.ndarray,
                                calib: StereoCalibration) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``line_reprojection_error``: (2,6) w.r.t. xi and (2,6) w.r.t. (A_w, B_w)."""
    _, J_pose, J_A, J_B = line_residuals(T_cw, A_w, B_w, line_coeffs_l, calib, jacobians=True)
    J_pts = np.zeros((2, 6))
    J_pts[0, :3] = J_A[0]
    J_pts[1, 3:] = J_B[0]
    return J_pose[0], J_pts
