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


def extend_segment(A_w: np.ndarray, B_w: np.ndarray, segment_uv: np.ndarray, T_world_cam: np.ndarray,
                   calib: StereoCalibration, max_growth: float = 1.0,
                   min_ray_angle_deg: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Extend a line landmark's 3D segment to cover a new observation (issue 4 item 3).

    Each observed endpoint's viewing ray is intersected (closest point) with the
    landmark's infinite 3D line A + s (B - A); the segment grows to span s in
    [min(0, s1, s2), max(1, s1, s2)], as PL-SLAM does when a longer view of a line
    arrives. Endpoints are only pushed outwards, never inwards (a partial view does
    not shorten a line), growth per update is capped at ``max_growth`` times the
    current length, and rays nearly parallel to the line (no reliable closest point)
    are ignored.
    """
    A_w, B_w = np.asarray(A_w, float), np.asarray(B_w, float)
    d = B_w - A_w
    length2 = float(d @ d)
    if not np.isfinite(length2) or length2 < 1e-12:
        return A_w, B_w
    uv = np.asarray(segment_uv, float).reshape(2, 2)
    R, C = T_world_cam[:3, :3], T_world_cam[:3, 3]
    rays = np.column_stack([(uv[:, 0] - calib.cx) / calib.fx, (uv[:, 1] - calib.cy) / calib.fy, np.ones(2)]) @ R.T
    w0 = A_w - C
    a, c = length2, np.einsum("ij,ij->i", rays, rays)
    b = rays @ d
    denom = a * c - b**2
    # sin^2 of the ray/line angle = denom / (a c); too small = parallel, no closest point
    ok = denom > (a * c) * np.sin(np.radians(min_ray_angle_deg)) ** 2
    if not ok.any():
        return A_w, B_w
    s = (b * (rays @ w0) - c * (d @ w0)) / np.where(ok, denom, 1.0)
    s = np.clip(s[ok], -max_growth, 1.0 + max_growth)
    lo, hi = min(0.0, float(s.min())), max(1.0, float(s.max()))
    return A_w + lo * d, A_w + hi * d
