"""New map points between two keyframes (ORB-SLAM LocalMapping::CreateNewMapPoints with
ORBmatcher::SearchForTriangulation), as plain functions on arrays."""
from __future__ import annotations

import cv2
import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import unique_by_reference
from canopy.mono.params import MonoParams
from shared.types import StereoCalibration

_COS_PARALLAX_MAX = 0.9998   # ORB-SLAM CreateNewMapPoints: rays must diverge more than this
_EPIPOLE_MIN_PX = 100.0      # ORB-SLAM SearchForTriangulation: keypoints near the epipole are skipped
_SCALE_CONSISTENCY = 1.5     # ORB-SLAM ratioFactor: distance ratio vs octave ratio tolerance


def triangulate_pairs(T1_cw: np.ndarray, T2_cw: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Linear triangulation of normalised image points x1 (N,2), x2 (N,2) seen by cameras with
    poses T_cam_world; world points (N,3) (NaN where degenerate)."""
    P1, P2 = T1_cw[:3], T2_cw[:3]
    A = np.stack([x1[:, 0:1] * P1[2] - P1[0], x1[:, 1:2] * P1[2] - P1[1],
                  x2[:, 0:1] * P2[2] - P2[0], x2[:, 1:2] * P2[2] - P2[1]], axis=1)
    _, _, vt = np.linalg.svd(A)
    Xh = vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        return Xh[:, :3] / Xh[:, 3:4]


def new_points_between(a, b, calib: StereoCalibration, params: MonoParams, scale: float, pixel_sigma: float = 1.0):
    """ORB-SLAM CreateNewMapPoints for one keyframe pair: match the free keypoints of ``a``
    and ``b`` (``landmark < 0``) along epipolar bands (x_b^T F_ba x_a = 0 within the 1-DoF
    chi-square gate; keypoints next to the epipole skipped), best of two within the band by
    Hamming distance, each keypoint once; triangulate and keep the points with parallax, in
    front of both cameras, reprojecting within the 2-DoF gate, with distances that follow the
    pyramid levels. ``a``/``b`` carry ``T_world_cam``, ``uv``, ``octave``, ``descriptors`` and
    ``landmark``. Returns (keypoints of a, keypoints of b, world points (K,3))."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    Kinv = np.linalg.inv(calib.K)
    Tb = se3_inv(b.T_world_cam)
    ia = np.flatnonzero(a.landmark < 0)
    ib = np.flatnonzero(b.landmark < 0)
    if len(ia) == 0 or len(ib) == 0:
        return empty
    # the epipolar constraint (x_b^T F_ba x_a = 0) as a mask over every free pair, then the
    # two nearest descriptors inside the mask (OpenCV's brute-force Hamming matcher)
    T_ba = Tb @ a.T_world_cam                      # camera a -> camera b
    R, t = T_ba[:3, :3], T_ba[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    F = Kinv.T @ tx @ R @ Kinv
    lines = np.column_stack([a.uv[ia], np.ones(len(ia))]) @ F.T          # (na,3) lines in image b
    lines /= np.maximum(np.linalg.norm(lines[:, :2], axis=1), 1e-30)[:, None]   # unit normals: num = distance
    la, ub = lines.astype(np.float32), b.uv[ib].astype(np.float32)
    dist_px = la[:, 0:1] * ub[:, 0]                                         # (na,nb) point-line distances
    dist_px += la[:, 1:2] * ub[:, 1]                                        # (broadcast: BLAS is slow for
    dist_px += la[:, 2:3]                                                   #  an inner dimension of 3)
    np.abs(dist_px, out=dist_px)
    tol_b = (np.sqrt(params.epipolar_chi2) * pixel_sigma * scale ** b.octave[ib]).astype(np.float32)
    mask = dist_px < tol_b[None, :]
    # camera a's centre seen from b (the epipole): matches next to it carry no depth
    ca = Tb[:3, :3] @ a.T_world_cam[:3, 3] + Tb[:3, 3]
    if ca[2] > 1e-9:
        e = ca[:2] / ca[2] * [calib.fx, calib.fy] + [calib.cx, calib.cy]
        mask &= (((b.uv[ib] - e) ** 2).sum(1) > (_EPIPOLE_MIN_PX * scale ** b.octave[ib]) ** 2)[None, :]
    if not mask.any():
        return empty
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(np.ascontiguousarray(a.descriptors[ia]),
                                                   np.ascontiguousarray(b.descriptors[ib]), k=2,
                                                   mask=mask.astype(np.uint8))
    big = 1 << 20
    rows = [(m[0].queryIdx, m[0].trainIdx, m[0].distance, m[1].distance if len(m) > 1 else big)
            for m in knn if len(m) > 0]
    if not rows:
        return empty
    arr = np.array(rows)
    qa, rb, dist, second = arr[:, 0].astype(np.int64), arr[:, 1].astype(np.int64), arr[:, 2], arr[:, 3]
    keep = (dist <= params.triangulation_max_hamming) & (dist < params.triangulation_ratio * second)
    qa, rb, dist = qa[keep], rb[keep], dist[keep].astype(np.int64)
    u = unique_by_reference(qa, rb, dist)
    ka, kb = ia[qa[u]], ib[rb[u]]
    if len(ka) == 0:
        return empty
    good, Pw = checked_points(a, b, ka, kb, calib, params.chi2_mono, scale, pixel_sigma)
    return ka[good], kb[good], Pw[good]


def checked_points(a, b, ka: np.ndarray, kb: np.ndarray, calib: StereoCalibration, chi2_mono: float, scale: float,
                   pixel_sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM CreateNewMapPoints' tests of matched keypoints ``ka`` of ``a`` / ``kb`` of ``b``:
    triangulate, then parallax (cos < 0.9998), depth > 0 in both, reprojection within the 2-DoF
    gate in both, distance ratio following the octave ratio. Returns (good mask, world points)."""
    Kinv = np.linalg.inv(calib.K)
    Ta, Tb = se3_inv(a.T_world_cam), se3_inv(b.T_world_cam)
    xa = (np.column_stack([a.uv[ka], np.ones(len(ka))]) @ Kinv.T)[:, :2]
    xb = (np.column_stack([b.uv[kb], np.ones(len(kb))]) @ Kinv.T)[:, :2]
    Pw = triangulate_pairs(Ta, Tb, xa, xb)
    good = np.isfinite(Pw).all(1)
    Pw = np.where(good[:, None], Pw, 0.0)
    Oa, Ob = a.T_world_cam[:3, 3], b.T_world_cam[:3, 3]
    ra, rb_ = Pw - Oa, Pw - Ob
    na, nb = np.linalg.norm(ra, axis=1), np.linalg.norm(rb_, axis=1)
    cos_par = (ra * rb_).sum(1) / np.maximum(na * nb, 1e-30)
    good &= cos_par < _COS_PARALLAX_MAX
    Pa = Pw @ Ta[:3, :3].T + Ta[:3, 3]
    Pb = Pw @ Tb[:3, :3].T + Tb[:3, 3]
    good &= (Pa[:, 2] > 0) & (Pb[:, 2] > 0)
    sa = pixel_sigma * scale ** a.octave[ka]
    sb = pixel_sigma * scale ** b.octave[kb]
    for P, uv, s in ((Pa, a.uv[ka], sa), (Pb, b.uv[kb], sb)):
        with np.errstate(divide="ignore", invalid="ignore"):
            proj = P[:, :2] / P[:, 2:3] * [calib.fx, calib.fy] + [calib.cx, calib.cy]
        good &= ((proj - uv) ** 2).sum(1) < chi2_mono * s**2
    # scale consistency: distance ratio should follow the pyramid-level ratio
    ratio_dist = nb / np.maximum(na, 1e-30)
    ratio_oct = scale ** (a.octave[ka] - b.octave[kb]).astype(float)
    good &= (ratio_dist * _SCALE_CONSISTENCY >= ratio_oct) & (ratio_dist <= ratio_oct * _SCALE_CONSISTENCY)
    return good, Pw
