"""Monocular two-view initialisation the ORB-SLAM way (Mur-Artal et al., T-RO 2015, §IV).

Given matched pixels of a reference and a current frame:

1. Homography and fundamental-matrix hypotheses are computed in parallel inside RANSAC,
   both from the *same* random sets of 8 correspondences: the normalised DLT for H
   (Hartley & Zisserman Alg. 4.2; 8 points over-determine its 4-point minimal case) and
   the normalised 8-point algorithm with rank-2 enforcement for F (H&Z Alg. 11.1).
2. Each hypothesis is scored with symmetric transfer errors (ORB-SLAM Eq. 1):
   S_M = sum_i rho(d2_cr(x_c, x_r)) + rho(d2_rc(...)), rho(d2) = Gamma - d2 / sigma^2 where
   d2 / sigma^2 < T_M, else 0; T_H = 5.99 (2 DoF), T_F = 3.84 (1 DoF), Gamma = T_H for both
   so the scores are comparable.
3. The model is chosen by R_H = S_H / (S_H + S_F): the homography when R_H > 0.45.
4. Motion: the homography is decomposed (Faugeras / Malis & Vargas: up to 4 physically
   distinct solutions, ``cv2.decomposeHomographyMat``), or E = K^T F K gives four (R, t)
   (H&Z Result 9.19). Every hypothesis triangulates the inliers; a point is good when it is
   in front of both cameras, reprojects within ``reprojection_chi2`` and (for the parallax
   statistic) sees the two centres at an angle. The hypothesis with the most good points wins
   if it is unambiguous, has enough points, and enough parallax (>= 1 deg at ORB-SLAM's
   50th-largest parallax).
5. The map is scale-free: it is scaled so that the median depth in the reference camera is 1.

All scoring is vectorised over (hypothesis, correspondence).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy.mono.params import MonoParams

MODEL_HOMOGRAPHY, MODEL_FUNDAMENTAL = "H", "F"
_COS_PARALLAX_MIN = 0.99998   # ORB-SLAM CheckRT: rays closer than this are "at infinity"
_PARALLAX_RANK = 50           # ORB-SLAM reports the parallax of the 50th best-parallax point


@dataclass
class TwoViewResult:
    """A successful (or rejected, ``ok`` False) two-view reconstruction.

    ``T_cur_ref`` maps reference-camera points into the current camera; ``points_ref`` are
    the triangulated points in the reference camera (NaN where ``good`` is False), scaled so
    that their median depth is 1.
    """

    ok: bool
    model: str                    # "H" or "F"
    ratio_h: float                # R_H = S_H / (S_H + S_F)
    T_cur_ref: np.ndarray
    points_ref: np.ndarray        # (N,3)
    good: np.ndarray              # (N,) bool
    parallax_deg: float
    n_inliers: int
    reason: str = ""

    @property
    def n_good(self) -> int:
        return int(self.good.sum())


# --------------------------------------------------------------------------- model fitting

def normalise_points(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hartley normalisation as ORB-SLAM's Initializer::Normalize: centre the points and
    scale each axis by its mean absolute deviation. Returns (normalised (N,2), T (3,3))."""
    p = np.asarray(p, np.float64)
    mean = p.mean(axis=0)
    dev = np.abs(p - mean).mean(axis=0)
    s = 1.0 / np.where(dev > 1e-12, dev, 1.0)
    T = np.array([[s[0], 0.0, -mean[0] * s[0]], [0.0, s[1], -mean[1] * s[1]], [0.0, 0.0, 1.0]])
    return (p - mean) * s, T


def _null_vectors(A: np.ndarray) -> np.ndarray:
    """(S,9) least-squares null vectors of (S,m,9) systems: the eigenvector of A^T A with the
    smallest eigenvalue (on Hartley-normalised points this is as accurate as the SVD, and a
    batch of 9x9 symmetric eigenproblems is an order of magnitude cheaper than tall SVDs)."""
    _, v = np.linalg.eigh(np.swapaxes(A, 1, 2) @ A)
    return v[:, :, 0]


def homographies_dlt(p1n: np.ndarray, p2n: np.ndarray, sets: np.ndarray) -> np.ndarray:
    """(S,3,3) homographies x2 ~ H x1 by DLT from normalised points, one per row of ``sets``."""
    x1, y1 = p1n[sets, 0], p1n[sets, 1]
    x2, y2 = p2n[sets, 0], p2n[sets, 1]
    zero, one = np.zeros_like(x1), np.ones_like(x1)
    a = np.stack([zero, zero, zero, -x1, -y1, -one, y2 * x1, y2 * y1, y2], axis=-1)
    b = np.stack([x1, y1, one, zero, zero, zero, -x2 * x1, -x2 * y1, -x2], axis=-1)
    A = np.concatenate([a, b], axis=1)                       # (S, 2k, 9)
    return _null_vectors(A).reshape(-1, 3, 3)


def fundamentals_8point(p1n: np.ndarray, p2n: np.ndarray, sets: np.ndarray) -> np.ndarray:
    """(S,3,3) rank-2 fundamental matrices with x2^T F x1 = 0 (normalised 8-point)."""
    x1, y1 = p1n[sets, 0], p1n[sets, 1]
    x2, y2 = p2n[sets, 0], p2n[sets, 1]
    A = np.stack([x2 * x1, x2 * y1, x2, y2 * x1, y2 * y1, y2, x1, y1, np.ones_like(x1)], axis=-1)
    F = _null_vectors(A).reshape(-1, 3, 3)
    u, s, vt = np.linalg.svd(F)
    s[:, 2] = 0.0
    return u @ (s[:, :, None] * vt)


def _rows_times_points(M: np.ndarray, p: np.ndarray, k: int) -> np.ndarray:
    """(S,N) row k of the 3x3 matrices M (S,3,3) applied to homogeneous pixels (p, 1)."""
    return M[:, k, 0, None] * p[None, :, 0] + M[:, k, 1, None] * p[None, :, 1] + M[:, k, 2, None]


def _apply_h(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(S,N,2) images of pixels p (N,2) under homographies H (S,3,3)."""
    w = _rows_times_points(H, p, 2)
    w = np.where(np.abs(w) < 1e-12, 1e-12, w)
    return np.stack([_rows_times_points(H, p, 0) / w, _rows_times_points(H, p, 1) / w], axis=-1)


def score_homographies(H21: np.ndarray, p1: np.ndarray, p2: np.ndarray, sigma: float,
                       chi2: float) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM CheckHomography for a batch: (scores (S,), inliers (S,N))."""
    H12 = np.linalg.inv(H21)
    inv_s2 = 1.0 / sigma**2
    e2 = ((p2[None] - _apply_h(H21, p1)) ** 2).sum(-1) * inv_s2   # transfer into the current image
    e1 = ((p1[None] - _apply_h(H12, p2)) ** 2).sum(-1) * inv_s2   # and back into the reference
    in1, in2 = e1 < chi2, e2 < chi2
    score = np.where(in1, chi2 - e1, 0.0).sum(1) + np.where(in2, chi2 - e2, 0.0).sum(1)
    return score, in1 & in2


def score_fundamentals(F21: np.ndarray, p1: np.ndarray, p2: np.ndarray, sigma: float, chi2: float,
                       chi2_score: float) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM CheckFundamental for a batch: squared distances to the epipolar lines in
    both images, thresholded at ``chi2`` (1 DoF) and scored against ``chi2_score`` (2 DoF,
    the homography's, so that S_H and S_F are on one scale)."""
    inv_s2 = 1.0 / sigma**2
    # lines in the current image l2 = F x1, and in the reference image l1 = F^T x2
    a2, b2, c2 = (_rows_times_points(F21, p1, k) for k in range(3))
    Ft = np.swapaxes(F21, 1, 2)
    a1, b1, c1 = (_rows_times_points(Ft, p2, k) for k in range(3))
    e2 = (a2 * p2[None, :, 0] + b2 * p2[None, :, 1] + c2) ** 2 / np.maximum(a2 * a2 + b2 * b2, 1e-30) * inv_s2
    e1 = (a1 * p1[None, :, 0] + b1 * p1[None, :, 1] + c1) ** 2 / np.maximum(a1 * a1 + b1 * b1, 1e-30) * inv_s2
    in1, in2 = e1 < chi2, e2 < chi2
    score = np.where(in1, chi2_score - e1, 0.0).sum(1) + np.where(in2, chi2_score - e2, 0.0).sum(1)
    return score, in1 & in2


def ransac_sets(n: int, iterations: int, rng: np.random.Generator, size: int = 8) -> np.ndarray:
    """(iterations, size) index sets without repetition inside a set (shared by H and F)."""
    keys = rng.random((iterations, n))
    return np.argpartition(keys, size - 1, axis=1)[:, :size] if n > size else np.tile(np.arange(n), (iterations, 1))


def find_models(p1: np.ndarray, p2: np.ndarray, params: MonoParams, rng: np.random.Generator):
    """Best H and best F over the same RANSAC sets.

    Returns (H21, inliers_h, S_H, F21, inliers_f, S_F).
    """
    p1n, T1 = normalise_points(p1)
    p2n, T2 = normalise_points(p2)
    sets = ransac_sets(len(p1), params.ransac_iterations, rng)
    T2inv = np.linalg.inv(T2)
    Hs = T2inv @ homographies_dlt(p1n, p2n, sets) @ T1
    Fs = T2.T @ fundamentals_8point(p1n, p2n, sets) @ T1
    # degenerate sets (collinear points) give singular homographies: score them zero
    good_h = np.abs(np.linalg.det(Hs)) > 1e-12
    Hs[~good_h] = np.eye(3)
    sh, inl_h = score_homographies(Hs, p1, p2, params.sigma_px, params.chi2_homography)
    sh[~good_h] = 0.0
    sf, inl_f = score_fundamentals(Fs, p1, p2, params.sigma_px, params.chi2_fundamental, params.chi2_homography)
    bh, bf = int(np.argmax(sh)), int(np.argmax(sf))
    best_h = (Hs[bh], inl_h[bh], float(sh[bh]))
    best_f = (Fs[bf], inl_f[bf], float(sf[bf]))
    # Least-squares re-fit on all inliers of the best set (H&Z Alg. 4.6, last step; ORB-SLAM
    # keeps the 8-point model, whose noise alone can push good points over the CheckRT
    # reprojection gate): kept only when it scores higher.
    for _ in range(2):
        if best_h[1].sum() >= 8:
            Hr = T2inv @ homographies_dlt(p1n, p2n, np.flatnonzero(best_h[1])[None]) @ T1
            if abs(np.linalg.det(Hr[0])) > 1e-12:
                s, inl = score_homographies(Hr, p1, p2, params.sigma_px, params.chi2_homography)
                if s[0] > best_h[2]:
                    best_h = (Hr[0], inl[0], float(s[0]))
        if best_f[1].sum() >= 8:
            Fr = T2.T @ fundamentals_8point(p1n, p2n, np.flatnonzero(best_f[1])[None]) @ T1
            s, inl = score_fundamentals(Fr, p1, p2, params.sigma_px, params.chi2_fundamental, params.chi2_homography)
            if s[0] > best_f[2]:
                best_f = (Fr[0], inl[0], float(s[0]))
    return (*best_h, *best_f)


# --------------------------------------------------------------------------- motion

def triangulate(K: np.ndarray, R: np.ndarray, t: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of pixel pairs, cameras K[I|0] and K[R|t]; (N,3) in camera 1."""
    Kinv = np.linalg.inv(K)
    x1 = np.concatenate([p1, np.ones((len(p1), 1))], 1) @ Kinv.T
    x2 = np.concatenate([p2, np.ones((len(p2), 1))], 1) @ Kinv.T
    P1 = np.hstack([np.eye(3), np.zeros((3, 1))])
    P2 = np.hstack([R, np.asarray(t, float).reshape(3, 1)])
    A = np.stack([x1[:, 0:1] * P1[2] - P1[0], x1[:, 1:2] * P1[2] - P1[1],
                  x2[:, 0:1] * P2[2] - P2[0], x2[:, 1:2] * P2[2] - P2[1]], axis=1)   # (N,4,4)
    _, _, vt = np.linalg.svd(A, full_matrices=False)
    Xh = vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        return Xh[:, :3] / Xh[:, 3:4]


def check_motion(K: np.ndarray, R: np.ndarray, t: np.ndarray, p1: np.ndarray, p2: np.ndarray,
                 candidates: np.ndarray, reprojection_chi2: float, sigma: float):
    """ORB-SLAM CheckRT: triangulate the candidate correspondences and count the good ones.

    Returns (n_good, good (N,) bool, points (N,3) in camera 1, parallax_deg) where ``good``
    also requires a parallax above the "at infinity" angle.
    """
    n = len(p1)
    idx = np.flatnonzero(candidates)
    X = np.full((n, 3), np.nan)
    good = np.zeros(n, bool)
    if len(idx) == 0:
        return 0, good, X, 0.0
    Xc = triangulate(K, R, t, p1[idx], p2[idx])
    finite = np.isfinite(Xc).all(1)
    Xc = np.where(finite[:, None], Xc, 0.0)
    O2 = -R.T @ t
    n1 = Xc
    n2 = Xc - O2
    cos_par = (n1 * n2).sum(1) / np.maximum(np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1), 1e-30)
    X2 = Xc @ R.T + t
    has_par = cos_par < _COS_PARALLAX_MIN
    ok = finite & ~((Xc[:, 2] <= 0) & has_par) & ~((X2[:, 2] <= 0) & has_par)
    th = reprojection_chi2 * sigma**2
    with np.errstate(divide="ignore", invalid="ignore"):
        u1 = Xc[:, :2] / Xc[:, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]
        u2 = X2[:, :2] / X2[:, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]
        ok &= ((u1 - p1[idx]) ** 2).sum(1) <= th
        ok &= ((u2 - p2[idx]) ** 2).sum(1) <= th
    n_good = int(ok.sum())
    sel = ok & has_par
    good[idx[sel]] = True
    X[idx[sel]] = Xc[sel]
    if n_good == 0:
        return 0, good, X, 0.0
    cos_sorted = np.sort(cos_par[ok])
    parallax = float(np.degrees(np.arccos(np.clip(cos_sorted[min(_PARALLAX_RANK, len(cos_sorted) - 1)], -1, 1))))
    return n_good, good, X, parallax


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, float).reshape(3)
    return T


def motions_from_fundamental(F21: np.ndarray, K: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four (R, t) of E = K^T F K (H&Z Result 9.19), |t| = 1."""
    E = K.T @ F21 @ K
    R1, R2, t = cv2.decomposeEssentialMat(E)
    t = t.reshape(3)
    return [(R1, t), (R1, -t), (R2, t), (R2, -t)]


def motions_from_homography(H21: np.ndarray, K: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The physically distinct (R, t/d) of a calibrated homography (Malis & Vargas 2007)."""
    _, Rs, ts, _ = cv2.decomposeHomographyMat(H21, K)
    return [(np.asarray(R, float), np.asarray(t, float).reshape(3)) for R, t in zip(Rs, ts)]


def _select_motion(K, hypotheses, p1, p2, inliers, params: MonoParams, model: str):
    """Evaluate every (R, t) and keep the best one if it is unambiguous and well conditioned."""
    n_inl = int(inliers.sum())
    results = [check_motion(K, R, t, p1, p2, inliers, params.reprojection_chi2, params.sigma_px)
               for R, t in hypotheses]
    counts = np.array([r[0] for r in results])
    best = int(np.argmax(counts))
    n_best = int(counts[best])
    n_good, good, X, parallax = results[best]
    R, t = hypotheses[best]
    need = max(int(0.9 * n_inl), params.min_triangulated)
    if model == MODEL_HOMOGRAPHY:   # ORB-SLAM ReconstructH: second best < 0.75 x best
        ambiguous = np.sort(counts)[-2] >= 0.75 * n_best if len(counts) > 1 else False
    else:                           # ReconstructF: no other hypothesis within 0.7 x best
        ambiguous = int((counts > params.ambiguity_ratio * n_best).sum()) > 1
    reason = ""
    if n_best < need:
        reason = f"{n_best} good points < {need}"
    elif ambiguous:
        reason = "ambiguous motion hypotheses"
    elif parallax < params.min_parallax_deg:
        reason = f"parallax {parallax:.2f} deg < {params.min_parallax_deg}"
    return reason, R, t, good, X, parallax


def initialise_two_view(p_ref: np.ndarray, p_cur: np.ndarray, K: np.ndarray, params: MonoParams | None = None,
                        seed: int = 0) -> TwoViewResult:
    """Two-view reconstruction of matched pixels ``p_ref[i] <-> p_cur[i]`` (ORB-SLAM Initialize)."""
    params = params or MonoParams()
    p1 = np.asarray(p_ref, np.float64).reshape(-1, 2)
    p2 = np.asarray(p_cur, np.float64).reshape(-1, 2)
    n = len(p1)
    if n < 8:
        return TwoViewResult(False, "", 0.0, np.eye(4), np.full((n, 3), np.nan), np.zeros(n, bool), 0.0, 0,
                             f"{n} matches < 8")
    rng = np.random.default_rng(seed)
    H, inl_h, sh, F, inl_f, sf = find_models(p1, p2, params, rng)
    ratio_h = sh / (sh + sf) if sh + sf > 0 else 0.0
    if ratio_h > params.homography_ratio:
        model, inliers, hyps = MODEL_HOMOGRAPHY, inl_h, motions_from_homography(H, K)
    else:
        model, inliers, hyps = MODEL_FUNDAMENTAL, inl_f, motions_from_fundamental(F, K)
    reason, R, t, good, X, parallax = _select_motion(K, hyps, p1, p2, inliers, params, model)
    n_inl = int(inliers.sum())
    if reason:
        return TwoViewResult(False, model, ratio_h, _pose(R, t), X, good, parallax, n_inl, reason)
    # scale-free map: median depth of the reference camera = 1 (ORB-SLAM CreateInitialMapMonocular)
    median_depth = float(np.median(X[good, 2]))
    if not median_depth > 0:
        return TwoViewResult(False, model, ratio_h, _pose(R, t), X, good, parallax, n_inl, "median depth <= 0")
    return TwoViewResult(True, model, ratio_h, _pose(R, t / median_depth), X / median_depth, good, parallax, n_inl)
