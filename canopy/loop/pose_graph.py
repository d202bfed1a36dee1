"""SE(3) pose-graph optimisation after a loop (AGRI §3.4.2) and the corrections it implies.

AGRI solves the pose graph with g2o over the essential graph (spanning tree + strong
covisibility edges + loop edges, ORB-SLAM's OptimizeEssentialGraph); with stereo the scale
is observable, so the graph is over SE(3) rather than Sim(3) (ORB-SLAM2 stereo fixes the
Sim3 scale to 1). Here it is GTSAM: one ``BetweenFactorPose3`` per edge, measured as the
relative pose of the two keyframes in the map before the loop (odometry and covisibility
edges) or as verified (loop edges), with a Huber kernel so that a wrong edge cannot drag
the whole graph, and the oldest keyframe held by a tight prior (gauge freedom).

After the poses move, each landmark moves rigidly with its reference keyframe
(ORB-SLAM CorrectLoop: X' = T'_wr T_wr^-1 X), and keyframes the optimiser did not see
(inserted while it ran) move with the nearest older keyframe it did see.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.loop.params import LoopParams
from shared.arrays import unique_sorted

X = gtsam.symbol_shorthand.X

ODOMETRY, COVISIBILITY, LOOP = "odometry", "covisibility", "loop"


@dataclass(frozen=True)
class PoseGraphEdge:
    i: int
    j: int
    T_i_j: np.ndarray   # (4,4) pose of keyframe j in keyframe i's camera frame
    kind: str           # odometry | covisibility | loop


@dataclass
class PoseGraphResult:
    poses: dict[int, np.ndarray]   # optimised T_world_cam
    initial_error: float
    final_error: float
    iterations: int


def relative(T_w_i: np.ndarray, T_w_j: np.ndarray) -> np.ndarray:
    return se3_inv(T_w_i) @ T_w_j


def essential_graph_edges(order: list[int], poses: dict[int, np.ndarray], covisibility: dict[tuple[int, int], int],
                          loops: list[PoseGraphEdge], min_shared: int) -> list[PoseGraphEdge]:
    """ORB-SLAM's essential graph: each keyframe tied to the one before it (our spanning tree:
    keyframes arrive in order), strong covisibility pairs (>= ``min_shared`` landmarks), and
    the loop edges; the non-loop edges carry the relative poses the map has now."""
    edges = [PoseGraphEdge(a, b, relative(poses[a], poses[b]), ODOMETRY) for a, b in zip(order[:-1], order[1:])]
    consecutive = set(zip(order[:-1], order[1:]))
    for (a, b), n in sorted(covisibility.items()):
        if n >= min_shared and (a, b) not in consecutive and (b, a) not in consecutive and a in poses and b in poses:
            edges.append(PoseGraphEdge(a, b, relative(poses[a], poses[b]), COVISIBILITY))
    return edges + list(loops)


def optimise_pose_graph(poses: dict[int, np.ndarray], edges: list[PoseGraphEdge], params: LoopParams,
                        fixed: int | None = None) -> PoseGraphResult:
    """Levenberg-Marquardt over SE(3) poses; ``fixed`` (default: the smallest id) is held."""
    if not poses:
        return PoseGraphResult({}, 0.0, 0.0, 0)
    fixed = min(poses) if fixed is None else fixed
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, T in poses.items():
        values.insert(X(k), gtsam.Pose3(np.asarray(T, float)))
    graph.add(gtsam.PriorFactorPose3(X(fixed), gtsam.Pose3(np.asarray(poses[fixed], float)),
                                     gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(params.robust_kernel_k)
    # GTSAM's Pose3 tangent is (rotation, translation)
    noise = {kind: gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(
        np.array([sr] * 3 + [st] * 3)))
        for kind, sr, st in ((ODOMETRY, params.odometry_sigma_rot, params.odometry_sigma_trans),
                             (COVISIBILITY, params.odometry_sigma_rot, params.odometry_sigma_trans),
                             (LOOP, params.loop_sigma_rot, params.loop_sigma_trans))}
    for e in edges:
        if e.i in poses and e.j in poses:
            graph.add(gtsam.BetweenFactorPose3(X(e.i), X(e.j), gtsam.Pose3(np.asarray(e.T_i_j, float)), noise[e.kind]))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(params.pgo_max_iterations)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    initial_error = graph.error(values)
    result = optimizer.optimize()
    out = {k: result.atPose3(X(k)).matrix() for k in poses}
    return PoseGraphResult(out, float(initial_error), float(graph.error(result)), int(optimizer.iterations()))


def pose_corrections(before: dict[int, np.ndarray], after: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """World-frame correction C_k = T'_k T_k^-1 of every optimised keyframe."""
    return {k: after[k] @ se3_inv(before[k]) for k in after if k in before}


def correction_for(kf: int, corrections: dict[int, np.ndarray]) -> np.ndarray:
    """The correction of ``kf``, or of the nearest older corrected keyframe (a keyframe the
    optimiser did not see rides with the map it was tracked against); identity if none."""
    C = corrections.get(kf)
    if C is not None:
        return C
    older = [k for k in corrections if k < kf]
    return corrections[max(older)] if older else np.eye(4)


def correct_landmarks(positions: np.ndarray, reference_kf: np.ndarray, corrections: dict[int, np.ndarray]) -> np.ndarray:
    """X' = C_ref X for each landmark, C_ref the correction of its reference keyframe."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    reference_kf = np.asarray(reference_kf, np.int64).reshape(-1)
    out = positions.copy()
    for r in unique_sorted(reference_kf).tolist():
        sel = reference_kf == r
        C = correction_for(int(r), corrections)
        out[sel] = positions[sel] @ C[:3, :3].T + C[:3, 3]
    return out
