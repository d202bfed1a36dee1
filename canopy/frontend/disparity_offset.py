"""Calibration of a constant stereo disparity offset (the "doffs" of a rectified rig).

A rectified pair whose right principal point is off by a fraction of a pixel measures every
disparity off by a constant ``delta``: d_true = d_measured + delta. Depth z = bf / d then has
a relative error delta / d that grows with distance, and stereo tracking over-estimates the
motion: a landmark first seen at depth z and later at z - t implies a motion of about
t (1 + 2 delta z / bf), farther points more. On the real KITTI 06 frames Canopy's path was
0.95 % long for this reason (its sub-pixel disparities agree with OpenCV's SGBM to 0.03 px,
and generated sequences with an exact calibration show no bias); recalibration of the KITTI
rig is known to improve stereo odometry (Cvišić, Marković, Petrović, "Recalibrating the
KITTI dataset camera setup for improved odometry accuracy", ECMR 2021).

Because the error depends on depth, the offset is observable from the images alone: for
points seen with stereo in two frames, ``estimate_disparity_offset`` solves a two-frame
stereo bundle adjustment in which the points, the relative pose and the offset are free.
One pair constrains the offset only weakly (sd ~0.7 px on KITTI), so a single run cannot
self-calibrate online reliably; the median over all consecutive pairs of a sequence can
(benchmarks/calibrate_disparity_offset.py): 0.20 px on the KITTI 06 snippet, -0.03 px on the
generated day-loop whose calibration is exact. The value goes to the dataset's config
(``tracking.disparity_offset_px``). No ground truth is used.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.geometry import se3_exp
from shared.types import StereoCalibration

_HUBER = 1.5  # whitened residual where the Huber kernel turns linear


def _triangulate(uv: np.ndarray, disp: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    z = calib.bf / disp
    return np.stack([(uv[:, 0] - calib.cx) * z / calib.fx, (uv[:, 1] - calib.cy) * z / calib.fy, z], axis=1)


def _project(P: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    iz = 1.0 / P[:, 2]
    return np.stack([calib.fx * P[:, 0] * iz + calib.cx, calib.fy * P[:, 1] * iz + calib.cy, calib.bf * iz], axis=1)


def _point_jacobian(P: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    """(N,3,3) d(u, v, disparity)/dP for camera-frame points P."""
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    iz = 1.0 / z
    J = np.zeros((len(P), 3, 3))
    J[:, 0, 0] = calib.fx * iz
    J[:, 0, 2] = -calib.fx * x * iz * iz
    J[:, 1, 1] = calib.fy * iz
    J[:, 1, 2] = -calib.fy * y * iz * iz
    J[:, 2, 2] = -calib.bf * iz * iz
    return J


def _huber_weights(r: np.ndarray) -> np.ndarray:
    """Per point and frame: Huber weight of the whitened 3-vector residual norm."""
    e = np.linalg.norm(r, axis=-1)
    return np.where(e <= _HUBER, 1.0, _HUBER / np.maximum(e, 1e-12))


def estimate_disparity_offset(uv1: np.ndarray, disp1: np.ndarray, sigma1: np.ndarray,
                              uv2: np.ndarray, disp2: np.ndarray, sigma2: np.ndarray,
                              T21: np.ndarray, calib: StereoCalibration,
                              iterations: int = 8) -> tuple[float, float, np.ndarray]:
    """Two-frame stereo bundle adjustment with a disparity offset: the points (frame-1
    coordinates), the relative pose T21 (frame 1 -> frame 2 camera) and the offset are all
    free, every point measured as (u, v, disparity + offset) in both frames. Points are free
    variables (not triangulated from one noisy disparity), so the estimate does not absorb
    the bias of bf / d under disparity noise. Gauss-Newton with the points eliminated by the
    Schur complement, Huber weights per observation.

    Returns (offset px, its standard deviation px, refined T21). The standard deviation is
    inf when the pair does not constrain the offset (no motion: it then cancels).
    """
    uv1, uv2 = np.asarray(uv1, float), np.asarray(uv2, float)
    d1, d2 = np.asarray(disp1, float), np.asarray(disp2, float)
    w1, w2 = 1.0 / np.asarray(sigma1, float) ** 2, 1.0 / np.asarray(sigma2, float) ** 2
    P = _triangulate(uv1, d1, calib)
    T = np.asarray(T21, float).copy()
    delta = 0.0
    n = len(P)
    S = np.zeros((7, 7))
    for _ in range(iterations):
        R, t = T[:3, :3], T[:3, 3]
        P2 = P @ R.T + t
        if (P[:, 2] <= 0).any() or (P2[:, 2] <= 0).any():
            return 0.0, float("inf"), T21
        r1 = _project(P, calib) - np.column_stack([uv1, d1 + delta])
        r2 = _project(P2, calib) - np.column_stack([uv2, d2 + delta])
        h1 = w1 * _huber_weights(r1 * np.sqrt(w1)[:, None])
        h2 = w2 * _huber_weights(r2 * np.sqrt(w2)[:, None])
        J1 = _point_jacobian(P, calib)                       # d r1 / dP
        Jq = _point_jacobian(P2, calib)                      # d r2 / dP2
        J2 = Jq @ R                                          # d r2 / dP
        Jc = np.zeros((n, 3, 7))                             # d r2 / (xi, delta)
        dP2 = np.zeros((n, 3, 6))
        dP2[:, 0, 1], dP2[:, 0, 2] = P2[:, 2], -P2[:, 1]
        dP2[:, 1, 0], dP2[:, 1, 2] = -P2[:, 2], P2[:, 0]
        dP2[:, 2, 0], dP2[:, 2, 1] = P2[:, 1], -P2[:, 0]
        dP2[:, 0, 3] = dP2[:, 1, 4] = dP2[:, 2, 5] = 1.0
        Jc[:, :, :6] = Jq @ dP2
        Jc[:, 2, 6] = -1.0
        Jd1 = np.zeros((n, 3))                               # d r1 / delta
        Jd1[:, 2] = -1.0
        Hpp = (np.einsum("nki,n,nkj->nij", J1, h1, J1) + np.einsum("nki,n,nkj->nij", J2, h2, J2))
        Hpc = np.einsum("nki,n,nkj->nij", J2, h2, Jc)
        Hpc[:, :, 6] += np.einsum("nki,n,nk->ni", J1, h1, Jd1)
        Hcc = np.einsum("nki,n,nkj->ij", Jc, h2, Jc)
        Hcc[6, 6] += float(np.sum(h1))
        gp = np.einsum("nki,n,nk->ni", J1, h1, r1) + np.einsum("nki,n,nk->ni", J2, h2, r2)
        gc = np.einsum("nki,n,nk->i", Jc, h2, r2)
        gc[6] += float(np.einsum("nk,n,nk->", Jd1, h1, r1))
        try:
            Hpp_inv = np.linalg.inv(Hpp)
        except np.linalg.LinAlgError:
            return 0.0, float("inf"), T21
        HcpHi = np.einsum("nji,njk->nik", Hpc, Hpp_inv)       # Hpc^T Hpp^-1  (n,7,3)
        S = Hcc - np.einsum("nik,nkj->ij", HcpHi, Hpc)
        b = gc - np.einsum("nik,nk->i", HcpHi, gp)
        try:
            dc = -np.linalg.solve(S, b)
        except np.linalg.LinAlgError:
            return 0.0, float("inf"), T21
        dp = -np.einsum("nij,nj->ni", Hpp_inv, gp + Hpc @ dc)
        P = P + dp
        T = se3_exp(dc[:6]) @ T
        delta += dc[6]
        if np.abs(dc).max() < 1e-7:
            break
    try:
        var = np.linalg.inv(S)[6, 6]
    except np.linalg.LinAlgError:
        return 0.0, float("inf"), T21
    sd = float(np.sqrt(var)) if np.isfinite(var) and var > 0 else float("inf")
    return float(delta), sd, T
