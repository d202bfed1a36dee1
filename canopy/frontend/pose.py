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
from typing import Protocol

import numpy as np

from canopy.frontend.geometry import _norm, project_stereo, se3_exp, stereo_pose_jacobian, pose_information
from shared.types import StereoCalibration

_MIN_DEPTH = 1e-6
_CONVERGED_STEP = 1e-6  # |dxi| below which Gauss-Newton has converged (rad / m: 1 µrad, 1 µm)


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


class ExtraTerms(Protocol):
    """More residuals for ``refine_pose`` (e.g. the Eq. 10 line terms), with their own
    inlier set: frozen at ``start_round``, re-classified by ``classify`` after a round."""

    def start_round(self) -> int: ...          # returns the number of scalar residuals in play
    def normal_equations(self, T_cw: np.ndarray, robust: bool) -> tuple[np.ndarray, np.ndarray]: ...
    def classify(self, T_cw: np.ndarray) -> None: ...
    def information(self, T_cw: np.ndarray) -> np.ndarray: ...


def refine_pose(T_cw: np.ndarray, X_w: np.ndarray, meas: np.ndarray, has_right: np.ndarray,
                sigma: np.ndarray, calib: StereoCalibration, rounds: int, iterations: int,
                chi2_mono: float, chi2_stereo: float, inliers: np.ndarray | None = None,
                extra: ExtraTerms | None = None) -> PoseEstimate:
    """Gauss-Newton on the point terms (Eq. 9) plus optional ``extra`` terms (Eq. 11)."""
    X_w = np.asarray(X_w, float).reshape(-1, 3)
    meas = np.asarray(meas, float).reshape(-1, 3)
    hr = np.asarray(has_right, float).reshape(-1)
    sigma = np.asarray(sigma, float).reshape(-1)
    thr = np.where(hr > 0, chi2_stereo, chi2_mono)
    inl = np.ones(len(X_w), bool) if inliers is None else inliers.copy()
    T = T_cw.copy()
    for rnd in range(rounds):
        robust = rnd < rounds - 1  # the Huber kernel is dropped in the last round
        # the inlier sets change between rounds only
        idx = np.flatnonzero(inl)
        Xr, mr, hrr, sr, kr = X_w[idx], meas[idx], hr[idx], sigma[idx], np.sqrt(thr[idx])
        n_residuals = 3 * len(idx) + (extra.start_round() if extra is not None else 0)
        for _ in range(iterations if n_residuals >= 6 else 0):
            H, g = np.zeros((6, 6)), np.zeros(6)
            if len(idx):
                chi2, r, Pc = measurement_chi2(T, Xr, mr, hrr, sr, calib)
                front = np.isfinite(chi2)
                w = np.where(front, 1.0 / sr**2, 0.0)
                if robust:  # Huber weight on the whitened residual norm
                    e = np.sqrt(np.where(front, chi2, 0.0))
                    w = w * np.where(e <= kr, 1.0, kr / np.maximum(e, 1e-12))
                Pc = np.where(front[:, None], Pc, 1.0)  # rows behind the camera carry zero weight
                r = np.where(front[:, None], r, 0.0)
                J = stereo_pose_jacobian(Pc, calib).reshape(-1, 6)
                W = np.repeat(w[:, None], 3, axis=1)
                W[:, 2] *= hrr
                JW = J * W.reshape(-1, 1)
                H += JW.T @ J
                g += JW.T @ r.reshape(-1)
            if extra is not None:
                He, ge = extra.normal_equations(T, robust)
                H += He
                g += ge
            try:
                dx = np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                break
            T = se3_exp(dx) @ T
            if _norm(dx) < _CONVERGED_STEP:  # np.linalg.norm's sqrt(dx . dx), without its overhead
                break
        chi2, _, _ = measurement_chi2(T, X_w, meas, hr, sigma, calib)
        inl = chi2 <= thr
        if extra is not None:
            extra.classify(T)
    chi2, _, Pc = measurement_chi2(T, X_w, meas, hr, sigma, calib)
    inl = chi2 <= thr
    info = np.zeros((6, 6))
    if inl.any():
        info += pose_information(stereo_pose_jacobian(Pc[inl], calib), sigma[inl], hr[inl])
    if extra is not None:
        extra.classify(T)
        info += extra.information(T)
    return PoseEstimate(T, inl, info, chi2)
