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

import cv2
import numpy as np

from canopy.frontend.geometry import (PoseJacobianBuffer, _norm, pose_information, project_stereo, se3_exp,
                                      stereo_pose_jacobian, transform)
from shared.types import StereoCalibration

_MIN_DEPTH = 1e-6
# |dxi| below which Gauss-Newton has converged (rad / m: 10 µrad, 10 µm). After a step of s the pose
# is within ~s^2 of the optimum; 1e-6 spent ~2 more iterations per call on nanometres (KITTI: -0.7 ms
# per frame at 1e-5). 1e-4 saved more but moved a chaotic grid cell (dark-rows g1-b0.06-high) below
# ORB-SLAM3: docs/notes/s13-speed.md.
_CONVERGED_STEP = 1e-5


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
    """Gauss-Newton on the point terms (Eq. 9) plus optional ``extra`` terms (Eq. 11).

    Every value is computed by the same operations as ``measurement_chi2`` and
    ``stereo_pose_jacobian`` would (bit-identical poses); what the loop saves is passes over the
    arrays: the rows in play, their sigma^2 and Huber widths are fixed per round, the residuals
    are formed column by column, the Jacobian's constant entries are written once a round
    (``PoseJacobianBuffer``), the masking ``np.where``s run only when a point is behind the camera,
    and the last round's classification is the final one (same pose, same chi-square)."""
    X_w = np.asarray(X_w, float).reshape(-1, 3)
    meas = np.asarray(meas, float).reshape(-1, 3)
    hr = np.asarray(has_right, float).reshape(-1)
    sigma = np.asarray(sigma, float).reshape(-1)
    thr = np.where(hr > 0, chi2_stereo, chi2_mono)
    inl = np.ones(len(X_w), bool) if inliers is None else inliers.copy()
    T = T_cw.copy()
    chi2_all = Pc_all = None
    for rnd in range(rounds):
        robust = rnd < rounds - 1  # the Huber kernel is dropped in the last round
        # the inlier sets change between rounds only
        idx = np.flatnonzero(inl)
        n_residuals = 3 * len(idx) + (extra.start_round() if extra is not None else 0)
        if len(idx):
            terms = _PointTerms(X_w[idx], meas[idx], hr[idx], sigma[idx], np.sqrt(thr[idx]), calib)
        for _ in range(iterations if n_residuals >= 6 else 0):
            H, g = np.zeros((6, 6)), np.zeros(6)
            if len(idx):
                JW, J, r = terms.weighted(T, robust)
                H += JW.T @ J
                g += JW.T @ r
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
        chi2_all, _, Pc_all = measurement_chi2(T, X_w, meas, hr, sigma, calib)
        inl = chi2_all <= thr
        if extra is not None:
            extra.classify(T)
    if chi2_all is None:  # no round
        chi2_all, _, Pc_all = measurement_chi2(T, X_w, meas, hr, sigma, calib)
    # the last round's classification, at the final pose, is the final one
    chi2, Pc = chi2_all, Pc_all
    inl = chi2 <= thr
    info = np.zeros((6, 6))
    if inl.any():
        info += pose_information(stereo_pose_jacobian(Pc[inl], calib), sigma[inl], hr[inl])
    if extra is not None:
        extra.classify(T)
        info += extra.information(T)
    return PoseEstimate(T, inl, info, chi2)


class _PointTerms:
    """The point residuals of one round of ``refine_pose`` (the rows in play fixed): per
    Gauss-Newton iteration the weighted Jacobian, the Jacobian and the residuals, each value as
    ``measurement_chi2`` / ``stereo_pose_jacobian`` and the Huber weighting compute it."""

    def __init__(self, X, meas, has_right, sigma, huber_width, calib: StereoCalibration):
        self.X, self.hr, self.k, self.calib = X, has_right, huber_width, calib
        self.m0, self.m1, self.m2 = meas[:, 0], meas[:, 1], meas[:, 2]
        self.s2 = sigma**2
        self.inv_s2 = 1.0 / self.s2
        n = len(X)
        self.r = np.empty((n, 3))
        self.W = np.empty((n, 3))
        self.jac = PoseJacobianBuffer(n)

    def weighted(self, T: np.ndarray, robust: bool):
        c, r = self.calib, self.r
        Pc = transform(T, self.X)
        z = Pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            inv_z = 1.0 / z
            u = c.fx * Pc[:, 0] * inv_z + c.cx
            np.subtract(self.m0, u, out=r[:, 0])
            np.subtract(self.m1, c.fy * Pc[:, 1] * inv_z + c.cy, out=r[:, 1])
            np.subtract(self.m2, u - c.bf * inv_z, out=r[:, 2])
            r[:, 2] *= self.hr
            r0, r1, r2 = r[:, 0], r[:, 1], r[:, 2]
            chi2 = (r0 * r0 + r1 * r1 + r2 * r2) / self.s2  # = (r**2).sum(axis=1) / sigma**2
        behind = z <= _MIN_DEPTH
        if behind.any():  # rows behind the camera carry zero weight
            chi2[behind] = np.inf
            front = np.isfinite(chi2)
            w = np.where(front, self.inv_s2, 0.0)
            e = np.sqrt(np.where(front, chi2, 0.0)) if robust else None
            Pc = np.where(front[:, None], Pc, 1.0)
            r = np.where(front[:, None], r, 0.0)
        else:
            front = np.isfinite(chi2)
            if front.all():
                w = self.inv_s2
                e = np.sqrt(chi2) if robust else None
            else:  # (a non-finite residual in front of the camera: as the masked form)
                w = np.where(front, self.inv_s2, 0.0)
                e = np.sqrt(np.where(front, chi2, 0.0)) if robust else None
                Pc = np.where(front[:, None], Pc, 1.0)
                r = np.where(front[:, None], r, 0.0)
        if robust:  # Huber weight on the whitened residual norm
            k = self.k
            w = w * np.where(e <= k, 1.0, k / np.maximum(e, 1e-12))
        J = self.jac(Pc, c).reshape(-1, 6)
        W = self.W
        W[:, 0] = w
        W[:, 1] = w
        np.multiply(w, self.hr, out=W[:, 2])
        return J * W.reshape(-1, 1), J, r.reshape(-1)


class MotionPrior:
    """A Gaussian prior on the pose (``ExtraTerms`` of ``refine_pose``): the refined pose is pulled
    toward a predicted pose ``T_pred_cw`` (the constant-velocity model's, T_last V) with standard
    deviations ``sigma_rot`` (rad) and ``sigma_trans`` (m) per axis of the camera frame.

    The residual is r = log(T_pred T^-1) ~ (rotation vector of R_pred R^T, t_pred - R_pred R^T t)
    (first order in the small increment; the exact SE(3) log differs by O(|omega| |t|)), so with the
    left increment T <- exp(dx) T it moves as r - dx: Jacobian I, normal equations Lambda and
    Lambda r with Lambda = diag(1/sigma_rot^2 x3, 1/sigma_trans^2 x3). This is the prediction step of
    a constant-velocity VO filter (Davison et al., MonoSLAM, PAMI 2007, §3.3: a constant-velocity
    model with white-noise acceleration) folded into the motion-only least squares as a pseudo-
    measurement, where ORB-SLAM's motion model only seeds the search. In Gauss-Newton the prior's
    pull is information-weighted by construction: the step solves (H_meas + Lambda) dx = g_meas +
    Lambda r, so it moves the pose only along directions where H_meas is comparable to Lambda
    (few, near, noisy points), not where the measurements are strong. It adds no robust kernel and
    no inlier set, and no information to the pose's (the entropy of AGRI Eq. 6 stays the
    measurements')."""

    def __init__(self, T_pred_cw: np.ndarray, sigma_rot, sigma_trans, pose_variance: np.ndarray | None = None):
        """``sigma_rot`` / ``sigma_trans``: scalars or per-axis (3,); <= 0 leaves that part out.
        ``pose_variance`` (6,): variances added per axis (the prediction's own uncertainty: a
        filter's predicted covariance is the process noise plus the propagated state's)."""
        self.T_pred = np.asarray(T_pred_cw, float)
        sig = np.concatenate([np.broadcast_to(np.asarray(sigma_rot, float), 3),
                              np.broadcast_to(np.asarray(sigma_trans, float), 3)])
        on = sig > 0
        var = sig**2 + (0.0 if pose_variance is None else np.asarray(pose_variance, float))
        self.weights = np.where(on, 1.0 / np.where(on, var, 1.0), 0.0)

    def residual(self, T_cw: np.ndarray) -> np.ndarray:
        R_d = self.T_pred[:3, :3] @ T_cw[:3, :3].T
        t_d = self.T_pred[:3, 3] - R_d @ T_cw[:3, 3]
        rvec, _ = cv2.Rodrigues(R_d)
        return np.concatenate([rvec.reshape(3), t_d])

    def start_round(self) -> int:
        return 0  # a prior, not measurements: it does not count toward the 6 residuals a pose needs

    def normal_equations(self, T_cw: np.ndarray, robust: bool) -> tuple[np.ndarray, np.ndarray]:
        return np.diag(self.weights), self.weights * self.residual(T_cw)

    def classify(self, T_cw: np.ndarray) -> None:
        pass

    def information(self, T_cw: np.ndarray) -> np.ndarray:
        return np.zeros((6, 6))
