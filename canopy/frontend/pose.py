"""Motion-only pose refinement on stereo reprojection errors (AGRI Eq. 8-9 with the map fixed).

After ORB-SLAM's Optimizer::PoseOptimization: ``rounds`` x ``iterations`` Gauss-Newton
steps on (u_l, v, u_r) residuals (u_r only where the keypoint has a stereo match), each
weighted by 1/sigma^2 with sigma = pixel_sigma * scale^octave and a Huber kernel of width
sqrt(chi2); after each round the measurements are re-classified as inliers/outliers by
their chi-square and the outliers leave the next round; the kernel is dropped in the last
round. Returns the pose, the inlier mask and the Fisher information J^T Sigma^-1 J at the
solution (its inverse is the pose covariance used by the entropy of AGRI Eq. 6).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy.frontend.geometry import project_stereo, se3_exp, stereo_pose_jacobian, pose_information
from shared.types import StereoCalibration

_MIN_DEPTH = 1e-6
_CONVERGED_STEP = 1e-8  # |dxi| below which Gauss-Newton has converged (rad / m)


@dataclass
class PoseEstimate:
    T_cam_world: np.ndarray
    inliers: np.ndarray       # (N,) bool
    information: np.ndarray   # (6,6) J^T Sigma^-1 J over the inliers
    chi2: np.ndarray          # (N,) final chi-square of every measurement


def measurement_chi2(T_cw, X_w, meas, has_right, sigma, calib):
    pred, Pc = project_stereo(T_cw, X_w, calib)
    r = meas - pred
    r[:, 2] *= has_right
    chi2 = (r**2).sum(axis=1) / sigma**2
    chi2[Pc[:, 2] <= _MIN_DEPTH] = np.inf
    return chi2, r, Pc


def refine_pose(T_cw: np.ndarray, X_w: np.ndarray, meas: np.ndarray, has_right: np.ndarray,
                sigma: np.ndarray, calib: StereoCalibration, rounds: int, iterations: int,
                chi2_mono: float, chi2_stereo: float, inliers: np.ndarray | None = None) -> PoseEstimate:
    X_w = np.asarray(X_w, float)
    meas = np.asarray(meas, float)
    hr = np.asarray(has_right, float)
    sigma = np.asarray(sigma, float)
    thr = np.where(hr > 0, chi2_stereo, chi2_mono)
    inl = np.ones(len(X_w), bool) if inliers is None else inliers.copy()
    T = T_cw.copy()
    for rnd in range(rounds):
        robust = rnd < rounds - 1
        for _ in range(iterations):
            idx = np.flatnonzero(inl)
            if len(idx) < 3:
                break
            chi2, r, Pc = measurement_chi2(T, X_w[idx], meas[idx], hr[idx], sigma[idx], calib)
            front = np.isfinite(chi2)
            idx, r, Pc, chi2 = idx[front], r[front], Pc[front], chi2[front]
            w = 1.0 / sigma[idx] ** 2
            if robust:  # Huber weight on the whitened residual norm
                e = np.sqrt(chi2)
                k = np.sqrt(thr[idx])
                w = w * np.where(e <= k, 1.0, k / np.maximum(e, 1e-12))
            J = stereo_pose_jacobian(Pc, calib)
            W = np.repeat(w[:, None], 3, axis=1)
            W[:, 2] *= hr[idx]
            H = np.einsum("nki,nk,nkj->ij", J, W, J)
            g = np.einsum("nki,nk,nk->i", J, W, r)
            try:
                dx = np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                break
            T = se3_exp(dx) @ T
            if np.linalg.norm(dx) < _CONVERGED_STEP:
                break
        chi2, _, _ = measurement_chi2(T, X_w, meas, hr, sigma, calib)
        inl = chi2 <= thr
    chi2, _, Pc = measurement_chi2(T, X_w, meas, hr, sigma, calib)
    inl = chi2 <= thr
    info = np.zeros((6, 6))
    if inl.any():
        J = stereo_pose_jacobian(Pc[inl], calib)
        info = pose_information(J, sigma[inl], hr[inl])
    return PoseEstimate(T, inl, info, chi2)
