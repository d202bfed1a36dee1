"""SE(3) helpers, stereo projection (AGRI Eq. 8), its pose Jacobian, pose covariance and
the differential entropy of AGRI Eq. 6.

Pose perturbations use GTSAM's tangent ordering xi = (omega, v) and act on the left of
``T_cam_world``: ``T <- exp(xi) @ T``. det(Sigma) is invariant under the SE(3) adjoint
(det Ad = det(R)^2 = 1), so the entropy does not depend on this choice.
"""
from __future__ import annotations

import numpy as np

from shared.types import StereoCalibration

_LOG_2PI_E = float(np.log(2.0 * np.pi * np.e))
_EYE3 = np.eye(3)
_EYE3.flags.writeable = False  # only ever added to: a new array each time


def skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _norm(w: np.ndarray) -> float:
    """``np.linalg.norm`` of a float vector (its own computation, sqrt(w . w)) without its
    argument handling: the pose refinement calls it ~30 times per frame."""
    return float(np.sqrt(w.dot(w)))


def _so3_exp(theta: float, W: np.ndarray, sin_t, one_minus_cos: float) -> np.ndarray:
    if theta < 1e-10:
        return _EYE3 + W
    return _EYE3 + sin_t / theta * W + one_minus_cos / theta**2 * W @ W


def so3_exp(w: np.ndarray) -> np.ndarray:
    w = np.asarray(w, float)
    theta = _norm(w)
    return _so3_exp(theta, skew(w), np.sin(theta), 1.0 - np.cos(theta))


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """exp of xi = (omega, v) as a 4x4 matrix. (theta, [w]x, sin and cos computed once for the
    rotation and V: the same values as computing them for each.)"""
    w, v = np.asarray(xi[:3], float), np.asarray(xi[3:], float)
    theta = _norm(w)
    W = skew(w)
    sin_t = cos_t = None
    if theta < 1e-10:
        V = _EYE3 + 0.5 * W
    else:
        sin_t, cos_t = np.sin(theta), np.cos(theta)
        V = _EYE3 + (1 - cos_t) / theta**2 * W + (theta - sin_t) / theta**3 * W @ W
    T = np.eye(4)
    T[:3, :3] = _so3_exp(theta, W, sin_t, None if cos_t is None else 1.0 - cos_t)
    T[:3, 3] = V @ v
    return T


def se3_inv(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    R = T[:3, :3]
    Ti[:3, :3] = R.T
    Ti[:3, 3] = -R.T @ T[:3, 3]
    return Ti


def rotation_angle(R: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def pose_from_rvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """OpenCV (rvec, tvec) of T_cam_world as a 4x4 matrix."""
    import cv2

    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, float).reshape(3)
    return T


def transform(T: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Apply a 4x4 pose to (N,3) points."""
    return X @ T[:3, :3].T + T[:3, 3]


def project_stereo(T_cw: np.ndarray, X_w: np.ndarray, calib: StereoCalibration) -> tuple[np.ndarray, np.ndarray]:
    """AGRI Eq. 8: (u_left, v, u_right) of world points, and their camera-frame coordinates."""
    Pc = transform(T_cw, X_w)
    z = Pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = 1.0 / z
        u = calib.fx * Pc[:, 0] * inv_z + calib.cx
        v = calib.fy * Pc[:, 1] * inv_z + calib.cy
        ur = u - calib.bf * inv_z
    return np.stack([u, v, ur], axis=1), Pc


def stereo_point_jacobian(Pc: np.ndarray, calib: StereoCalibration, min_depth: float | None = None) -> np.ndarray:
    """(N,3,3) Jacobian of the stereo projection (u_l, v, u_r) of AGRI Eq. 8 w.r.t. the camera-frame
    point Pc; ``min_depth`` clamps z (a BA iterate may put a point behind the camera)."""
    x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
    if min_depth is not None:
        z = np.maximum(z, min_depth)
    iz = 1.0 / z
    iz2 = iz * iz
    Jp = np.zeros((len(Pc), 3, 3))
    Jp[:, 0, 0] = calib.fx * iz
    Jp[:, 0, 2] = -calib.fx * x * iz2
    Jp[:, 1, 1] = calib.fy * iz
    Jp[:, 1, 2] = -calib.fy * y * iz2
    Jp[:, 2, 0] = calib.fx * iz
    Jp[:, 2, 2] = -calib.fx * (x - calib.baseline) * iz2
    return Jp


def stereo_pose_jacobian(Pc: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    """(N,3,6) Jacobian of (u_l, v, u_r) w.r.t. the left perturbation xi = (omega, v) of T_cam_world.

    dPc/dxi = [-[Pc]x | I]; d(u,v,ur)/dPc from Eq. 8 (ORB-SLAM's EdgeStereoSE3ProjectXYZOnlyPose).
    """
    x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
    n = len(Pc)
    Jp = stereo_point_jacobian(Pc, calib)
    dP = np.zeros((n, 3, 6))
    # -[Pc]x
    dP[:, 0, 1], dP[:, 0, 2] = z, -y
    dP[:, 1, 0], dP[:, 1, 2] = -z, x
    dP[:, 2, 0], dP[:, 2, 1] = y, -x
    dP[:, 0, 3] = dP[:, 1, 4] = dP[:, 2, 5] = 1.0
    return Jp @ dP


class PoseJacobianBuffer:
    """``stereo_pose_jacobian`` of n points, called again and again (the Gauss-Newton iterations of
    one ``refine_pose`` round): the entries that do not depend on the point (the zeros of d(u,v,ur)/dPc,
    the identity block and zeros of dPc/dxi) are written once, each call writes the 12 others, by the
    same products as ``stereo_point_jacobian`` / ``stereo_pose_jacobian``, and multiplies the same
    (n,3,3) @ (n,3,6) stack: the same values, without two (n,3,6)/(n,3,3) allocations and 12 fills."""

    def __init__(self, n: int):
        self.Jp = np.zeros((n, 3, 3))
        self.dP = np.zeros((n, 3, 6))
        self.dP[:, 0, 3] = self.dP[:, 1, 4] = self.dP[:, 2, 5] = 1.0

    def __call__(self, Pc: np.ndarray, calib: StereoCalibration) -> np.ndarray:
        x, y, z = Pc[:, 0], Pc[:, 1], Pc[:, 2]
        iz = 1.0 / z
        iz2 = iz * iz
        Jp, dP = self.Jp, self.dP
        fx_iz = calib.fx * iz
        Jp[:, 0, 0] = fx_iz
        Jp[:, 0, 2] = -calib.fx * x * iz2
        Jp[:, 1, 1] = calib.fy * iz
        Jp[:, 1, 2] = -calib.fy * y * iz2
        Jp[:, 2, 0] = fx_iz
        Jp[:, 2, 2] = -calib.fx * (x - calib.baseline) * iz2
        # -[Pc]x
        dP[:, 0, 1] = z
        np.negative(y, out=dP[:, 0, 2])
        np.negative(z, out=dP[:, 1, 0])
        dP[:, 1, 2] = x
        dP[:, 2, 0] = y
        np.negative(x, out=dP[:, 2, 1])
        return Jp @ dP


def pose_information(J: np.ndarray, sigma: np.ndarray, has_right: np.ndarray) -> np.ndarray:
    """Fisher information J^T Σ^-1 J of the pose from (N,3,6) stereo Jacobians.

    Rows for u_right are dropped where the measurement has no stereo match.
    """
    w = np.repeat((1.0 / np.asarray(sigma, float) ** 2)[:, None], 3, axis=1)
    w[:, 2] *= np.asarray(has_right, float)
    return np.einsum("nki,nk,nkj->ij", J, w, J)


def differential_entropy(cov: np.ndarray) -> float:
    """AGRI Eq. 6 for m = 6: h = 0.5 ln((2 pi e)^6 |Sigma|) = 3 (1 + ln 2pi) + 0.5 ln|Sigma|."""
    sign, logdet = np.linalg.slogdet(cov)
    if sign <= 0:
        return float("inf")
    m = cov.shape[0]
    return 0.5 * (m * _LOG_2PI_E + logdet)
