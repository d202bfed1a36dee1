"""Sim(3) for monocular loop closing (ORB-SLAM, Mur-Artal et al. T-RO 2015 §VI; Strasdat et
al., "Scale drift-aware large scale monocular SLAM", RSS 2010).

A monocular map has no metric scale and its scale drifts, so the constraint a loop adds
between two keyframes is a similarity, not a rigid motion, and the pose graph that spreads
it over the loop is over Sim(3): each keyframe gets a scale too.

Convention here: a similarity is the 4x4 matrix ``S = [s R  t; 0 1]`` acting on points as
``x -> s R x + t``. ``S_w_i`` maps camera-i coordinates (in the map units where camera i
was tracked) to the world; a camera's rigid pose is the rotation and the image of its
origin (``rigid_pose``). GTSAM's ``Similarity3(R, t', s)`` acts as ``s (R x + t')``, so
``t' = t / s`` (``to_gtsam`` / ``from_gtsam``).
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.metrics import umeyama_alignment

X = gtsam.symbol_shorthand.X


# --------------------------------------------------------------------------- algebra

def sim3_matrix(R: np.ndarray, t: np.ndarray, s: float) -> np.ndarray:
    S = np.eye(4)
    S[:3, :3] = float(s) * np.asarray(R, float)
    S[:3, 3] = np.asarray(t, float).reshape(3)
    return S


def sim3_parts(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, s) of ``S``: s is the cube root of det(sR)."""
    S = np.asarray(S, float)
    s = float(np.cbrt(np.linalg.det(S[:3, :3])))
    return S[:3, :3] / s, S[:3, 3].copy(), s


def sim3_inv(S: np.ndarray) -> np.ndarray:
    R, t, s = sim3_parts(S)
    return sim3_matrix(R.T, -(R.T @ t) / s, 1.0 / s)


def rigid_pose(S_w_c: np.ndarray) -> np.ndarray:
    """The camera pose (SE(3)) a similarity places: its rotation, and its origin's image as
    the camera centre (ORB-SLAM CorrectLoop: t / s of the corrected S_cw inverted)."""
    R, t, _ = sim3_parts(S_w_c)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def to_gtsam(S: np.ndarray) -> gtsam.Similarity3:
    R, t, s = sim3_parts(S)
    return gtsam.Similarity3(gtsam.Rot3(R), t / s, s)


def from_gtsam(g: gtsam.Similarity3) -> np.ndarray:
    s = float(g.scale())
    return sim3_matrix(g.rotation().matrix(), s * np.asarray(g.translation(), float), s)


# --------------------------------------------------------------------------- estimation

@dataclass
class Sim3Estimate:
    S: np.ndarray | None       # (4,4) maps points of set A onto set B: b ~ s R a + t
    inliers: np.ndarray        # (N,) bool
    reason: str = "ok"


def _project(P: np.ndarray, K: np.ndarray) -> np.ndarray:
    z = np.where(P[:, 2] > 1e-9, P[:, 2], np.nan)
    return np.stack([K[0, 0] * P[:, 0] / z + K[0, 2], K[1, 1] * P[:, 1] / z + K[1, 2]], axis=1)


def sim3_reprojection_inliers(S: np.ndarray, P_a: np.ndarray, P_b: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray,
                              K: np.ndarray, max_err_sq: np.ndarray, max_rel_3d: float | None = None) -> np.ndarray:
    """ORB-SLAM Sim3Solver::CheckInliers: a pair agrees when A's point mapped by S reprojects
    onto B's keypoint and B's point mapped back reprojects onto A's, both within the gate
    (``max_err_sq``: squared px per pair). Errors in pixels do not depend on the map scale.

    That is also their weakness: when the two cameras are close (a revisit along the same
    path) a point's depth barely changes its reprojection, so a wrong depth passes and pulls
    the scale of the refit. ``max_rel_3d`` adds the 3D test ``|s R a + t - b| <= max_rel_3d |b|``
    (the error relative to the point's distance, so it does not depend on the units)."""
    S_inv = sim3_inv(S)
    Pa_in_b = P_a @ S[:3, :3].T + S[:3, 3]
    e_b = np.sum((_project(Pa_in_b, K) - uv_b) ** 2, axis=1)
    e_a = np.sum((_project(P_b @ S_inv[:3, :3].T + S_inv[:3, 3], K) - uv_a) ** 2, axis=1)
    ok = (e_a < max_err_sq) & (e_b < max_err_sq)
    if max_rel_3d is not None:
        ok &= np.linalg.norm(Pa_in_b - P_b, axis=1) <= max_rel_3d * np.linalg.norm(P_b, axis=1)
    return np.where(np.isfinite(e_a) & np.isfinite(e_b), ok, False)


def estimate_sim3_ransac(P_a: np.ndarray, P_b: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray, K: np.ndarray,
                         max_err_sq, iterations: int = 200, min_inliers: int = 20, seed: int = 0,
                         max_rel_3d: float | None = None) -> Sim3Estimate:
    """Similarity between two keyframes' matched map points (each in its own camera frame and
    map units): Horn's closed form (Umeyama 1991, with scale) on 3-pair samples in RANSAC,
    inliers by two-way reprojection and, with ``max_rel_3d``, 3D agreement
    (``sim3_reprojection_inliers``), refitted on all inliers.
    ORB-SLAM Sim3Solver (Horn 1987 absolute orientation)."""
    P_a = np.asarray(P_a, float).reshape(-1, 3)
    P_b = np.asarray(P_b, float).reshape(-1, 3)
    n = len(P_a)
    max_err_sq = np.broadcast_to(np.asarray(max_err_sq, float), (n,))
    if n < max(3, min_inliers):
        return Sim3Estimate(None, np.zeros(n, bool), f"{n} point pairs < {max(3, min_inliers)}")
    rng = np.random.default_rng(seed)
    best = np.zeros(n, bool)
    for _ in range(iterations):
        idx = rng.choice(n, 3, replace=False)
        try:
            R, t, s = umeyama_alignment(P_a[idx].T, P_b[idx].T, with_scale=True)
        except ValueError:   # coincident sample points
            continue
        if not (np.isfinite(s) and s > 0):
            continue
        inl = sim3_reprojection_inliers(sim3_matrix(R, t, s), P_a, P_b, uv_a, uv_b, K, max_err_sq, max_rel_3d)
        if inl.sum() > best.sum():
            best = inl
    if best.sum() < max(3, min_inliers):
        return Sim3Estimate(None, best, f"Sim3 RANSAC: {int(best.sum())} inliers < {min_inliers}")
    inl = best
    for _ in range(2):   # refit on the consensus, then re-classify once more
        R, t, s = umeyama_alignment(P_a[inl].T, P_b[inl].T, with_scale=True)
        S = sim3_matrix(R, t, s)
        new = sim3_reprojection_inliers(S, P_a, P_b, uv_a, uv_b, K, max_err_sq, max_rel_3d)
        if new.sum() < max(3, min_inliers):
            break
        inl = new
    return Sim3Estimate(S, inl)


# --------------------------------------------------------------------------- pose graph

@dataclass
class Sim3GraphResult:
    poses: dict[int, np.ndarray]     # optimised S_w_i (similarities)
    initial_error: float
    final_error: float
    iterations: int


def optimise_sim3_pose_graph(poses: dict[int, np.ndarray], edges, sigmas: dict[str, tuple[float, float, float]],
                             robust_k: float, max_iterations: int, fixed: int | None = None) -> Sim3GraphResult:
    """ORB-SLAM OptimizeEssentialGraph (monocular): one Sim(3) per keyframe (its pose with
    scale 1 to start), a ``BetweenFactorSimilarity3`` per edge measuring ``S_i^-1 S_j``
    (``edge.T_i_j``, a rigid pose for odometry/covisibility edges, a similarity for a loop)
    under a Huber kernel; the ``fixed`` keyframe (default the oldest) is held by a tight prior.
    ``sigmas[kind] = (rotation rad, translation map units, log-scale)``; GTSAM's Sim(3)
    tangent is (rotation, translation, log-scale)."""
    if not poses:
        return Sim3GraphResult({}, 0.0, 0.0, 0)
    fixed = min(poses) if fixed is None else fixed
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, T in poses.items():
        values.insert(X(k), to_gtsam(T))
    graph.add(gtsam.PriorFactorSimilarity3(X(fixed), to_gtsam(poses[fixed]), gtsam.noiseModel.Isotropic.Sigma(7, 1e-6)))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(robust_k)
    noise = {kind: gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(
        np.array([sr] * 3 + [st] * 3 + [ss]))) for kind, (sr, st, ss) in sigmas.items()}
    for e in edges:
        if e.i in poses and e.j in poses:
            graph.add(gtsam.BetweenFactorSimilarity3(X(e.i), X(e.j), to_gtsam(e.T_i_j), noise[e.kind]))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(max_iterations)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    initial_error = graph.error(values)
    result = optimizer.optimize()
    out = {k: from_gtsam(result.atSimilarity3(X(k))) for k in poses}
    return Sim3GraphResult(out, float(initial_error), float(graph.error(result)), int(optimizer.iterations()))


def sim3_corrections(before: dict[int, np.ndarray], after: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """World-frame correction C_k = S'_w_k T_w_k^-1 of every optimised keyframe: a map point
    observed from keyframe k moves to C_k X (ORB-SLAM CorrectLoop), the keyframe's pose to
    ``rigid_pose(C_k T_w_k)``."""
    return {k: after[k] @ se3_inv(before[k]) for k in after if k in before}
