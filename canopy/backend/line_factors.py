"""GTSAM factors for the line term of local BA (AGRI Eq. 10-11).

A line landmark is two ``Point3`` endpoints A, B (world). One observation of it in keyframe
k is the normalised infinite line l (``canopy.lines.line_coefficients``) of the segment seen
in the left image (or the right image: then the camera is the left one shifted by the
baseline along x). Its residual is Eq. 10, e = (l . pi~(T_ck A), l . pi~(T_ck B)) in pixels,
whitened by Sigma = line_sigma^2 I (Eq. 11).

Two formulations, chosen by ``MappingParams.line_factor``:

* ``"custom"`` (``line_custom_factor``): a ``gtsam.CustomFactor`` on (pose, A, B) with the
  exact Eq. 10 residual and the analytic Jacobians of ``canopy.lines.line_residuals``.
  GTSAM's Pose3 retracts on the right of T_world_cam: T_wc exp(xi) means
  T_cw <- exp(-xi) T_cw, so the pose Jacobian is minus the left-perturbation Jacobian of
  T_cw. Exact, but every evaluation is a Python callback.
* ``"projection"`` (``line_projection_factors``): per endpoint one C++
  ``GenericProjectionFactorCal3_S2`` whose measurement is the foot of the perpendicular from
  the endpoint's current projection onto l, with the 2x2 information
  n n^T / line_sigma^2 + t t^T / line_sigma_along^2 (n the line normal, t its direction).
  Its whitened error is (d / line_sigma, s / line_sigma_along) with d the Eq. 10 distance
  and s the along-line offset from the foot (zero where the graph is built, and weighted
  ~1e-6 as much as d): at C++ speed it minimises Eq. 10. The foot is recomputed from the
  current estimate every BA pass.
"""
from __future__ import annotations

from functools import partial

import gtsam
import numpy as np

from canopy.lines import line_residuals
from shared.types import StereoCalibration


def right_shift(calib: StereoCalibration) -> np.ndarray:
    """T_right_left of a rectified pair: x_right = x_left - baseline."""
    S = np.eye(4)
    S[0, 3] = -calib.baseline
    return S


def _adjoint_translation(t: np.ndarray) -> np.ndarray:
    """Adjoint (xi = (omega, v) ordering) of a pure translation: [[I, 0], [t^, I]]."""
    Ad = np.eye(6)
    Ad[3:, :3] = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    return Ad


def line_error_and_jacobians(T_wc: np.ndarray, A: np.ndarray, B: np.ndarray, coeffs: np.ndarray,
                             calib: StereoCalibration, right: bool):
    """Eq. 10 residual (2,) and its Jacobians in GTSAM's conventions: (2,6) w.r.t. the right
    retraction of Pose3 T_world_cam, (2,3) w.r.t. A and (2,3) w.r.t. B."""
    T_cw = np.linalg.inv(T_wc)
    S = right_shift(calib) if right else np.eye(4)
    e, J_left, J_A, J_B = line_residuals(S @ T_cw, A[None], B[None], coeffs[None], calib, jacobians=True)
    # perturbing T_cw on the left by xi perturbs S T_cw by Ad_S xi; GTSAM: xi_gtsam = -xi
    J_pose = -J_left[0] @ _adjoint_translation(S[:3, 3]) if right else -J_left[0]
    HA = np.zeros((2, 3))
    HB = np.zeros((2, 3))
    HA[0], HB[1] = J_A[0], J_B[0]
    return e[0], J_pose, HA, HB


def _custom_error(coeffs: np.ndarray, calib: StereoCalibration, right: bool, this: gtsam.CustomFactor,
                  values: gtsam.Values, H) -> np.ndarray:
    keys = this.keys()
    T_wc = values.atPose3(keys[0]).matrix()
    A = np.asarray(values.atPoint3(keys[1]), float)
    B = np.asarray(values.atPoint3(keys[2]), float)
    e, Jp, JA, JB = line_error_and_jacobians(T_wc, A, B, coeffs, calib, right)
    if H is not None:
        H[0], H[1], H[2] = Jp, JA, JB
    return e


def line_custom_factor(pose_key: int, a_key: int, b_key: int, coeffs: np.ndarray, calib: StereoCalibration,
                       noise: gtsam.noiseModel.Base, right: bool = False) -> gtsam.CustomFactor:
    """Exact Eq. 10 factor on (T_world_cam, A, B) with analytic Jacobians."""
    return gtsam.CustomFactor(noise, [pose_key, a_key, b_key],
                              partial(_custom_error, np.asarray(coeffs, float).copy(), calib, bool(right)))


def line_projection_measurements(T_wc: np.ndarray, P_w: np.ndarray, coeffs: np.ndarray, calib: StereoCalibration,
                                 right: np.ndarray, sigma: float, sigma_along: float):
    """Per endpoint observation: the foot of the perpendicular (N,2) and the information (N,2,2).

    ``T_wc`` (N,4,4), ``P_w`` (N,3) current endpoint estimates, ``coeffs`` (N,3), ``right`` (N,) bool.
    """
    T_cw = np.linalg.inv(T_wc)
    Pc = np.einsum("nij,nj->ni", T_cw[:, :3, :3], P_w) + T_cw[:, :3, 3]
    Pc[:, 0] -= np.where(right, calib.baseline, 0.0)
    z = np.where(Pc[:, 2] > 1e-6, Pc[:, 2], 1e-6)
    uv = np.column_stack([calib.fx * Pc[:, 0] / z + calib.cx, calib.fy * Pc[:, 1] / z + calib.cy])
    n = coeffs[:, :2]
    d = (n * uv).sum(axis=1) + coeffs[:, 2]        # Eq. 10 distance (normalised line)
    foot = uv - d[:, None] * n
    t = np.column_stack([-n[:, 1], n[:, 0]])
    info = (np.einsum("ni,nj->nij", n, n) / sigma**2 + np.einsum("ni,nj->nij", t, t) / sigma_along**2)
    return foot, info


def line_endpoint_measurements(T_wc: np.ndarray, A_w: np.ndarray, B_w: np.ndarray, coeffs: np.ndarray,
                               segs: np.ndarray, calib: StereoCalibration, right: np.ndarray, sigma: float,
                               sigma_along: float):
    """Measurements of both endpoints of every line observation: the observed segment's own
    endpoints (each landmark endpoint takes the one its projection is nearer to, the pairing
    with the smaller total distance), with the information of ``line_projection_measurements``
    (tight across the observed line, ``sigma_along`` px along it).

    The feet of the perpendiculars hold the endpoints only across the line: along it nothing
    remembers where the segment was seen, BA after BA lets both endpoints drift along their 3D
    line, and on KITTI 06 76 % of the map lines ended shorter than 1 cm. Tying each endpoint
    loosely to an observed endpoint keeps the landmark's extent where the images see it.
    Observations without a segment (NaN) fall back to the feet. Returns ((2,N,2) A and B
    measurements, (N,2,2) information).
    """
    footA, info = line_projection_measurements(T_wc, A_w, coeffs, calib, right, sigma, sigma_along)
    footB, _ = line_projection_measurements(T_wc, B_w, coeffs, calib, right, sigma, sigma_along)
    p1, p2 = segs[:, :2], segs[:, 2:]
    straight = np.linalg.norm(footA - p1, axis=1) + np.linalg.norm(footB - p2, axis=1)
    swapped = np.linalg.norm(footA - p2, axis=1) + np.linalg.norm(footB - p1, axis=1)
    swap = (swapped < straight)[:, None]
    mA = np.where(swap, p2, p1)
    mB = np.where(swap, p1, p2)
    have = np.isfinite(segs).all(axis=1)[:, None]
    return np.stack([np.where(have, mA, footA), np.where(have, mB, footB)]), info


def line_projection_factors(pose_keys, point_keys, feet, infos, right, K: gtsam.Cal3_S2,
                            calib: StereoCalibration, huber: float) -> list:
    """One ``GenericProjectionFactorCal3_S2`` per endpoint observation (see module doc)."""
    body_right = gtsam.Pose3(gtsam.Rot3(), np.array([calib.baseline, 0.0, 0.0]))
    kernel = gtsam.noiseModel.mEstimator.Huber.Create(huber)
    out = []
    for pk, lk, f, I, r in zip(pose_keys, point_keys, feet, infos, right):
        noise = gtsam.noiseModel.Robust.Create(kernel, gtsam.noiseModel.Gaussian.Information(I))
        if r:
            out.append(gtsam.GenericProjectionFactorCal3_S2(f, noise, int(pk), int(lk), K, body_right))
        else:
            out.append(gtsam.GenericProjectionFactorCal3_S2(f, noise, int(pk), int(lk), K))
    return out
