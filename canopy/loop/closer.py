"""The loop closer's whole per-keyframe step, free of processes (AGRI §3.4).

``LoopCloser.add_keyframe(kf, window_poses)`` keeps its copy of the keyframe poses in
step with local BA, runs detection and verification (``LoopDetector``), and on a
verified loop optimises the essential graph in SE(3) (``optimise_pose_graph``) over all
loop edges found so far, returning the per-keyframe corrections that local mapping
applies to its map.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from canopy.frontend.geometry import rotation_angle, se3_inv
from canopy.loop.detector import LoopDetector
from canopy.loop.keyframe import PlaceKeyframe
from canopy.loop.params import LoopParams
from canopy.loop.pose_graph import (LOOP, PoseGraphEdge, essential_graph_edges, optimise_pose_graph,
                                    pose_corrections)
from canopy.loop.verify import LoopConstraint
from shared.types import StereoCalibration


@dataclass
class LoopClosure:
    constraint: LoopConstraint
    corrections: dict[int, np.ndarray]       # keyframe -> C = T'_wc T_wc^-1
    poses_before: dict[int, np.ndarray]
    poses_after: dict[int, np.ndarray]
    pgo_error: tuple[float, float]           # graph error before / after
    timings_ms: dict = field(default_factory=dict)


class LoopCloser:
    def __init__(self, calib: StereoCalibration, params: LoopParams | None = None, vocabulary=None):
        self.params = (params or LoopParams()).validate()
        self.detector = LoopDetector(calib, self.params, vocabulary, plausible=self.drift_check)
        self.vocabulary = vocabulary
        self.poses: dict[int, np.ndarray] = {}
        self.loop_edges: list[PoseGraphEdge] = []
        self.closures: list[LoopClosure] = []

    def path_length(self, a: int, b: int) -> float:
        """Distance travelled between keyframes ``a`` and ``b`` along the keyframe sequence."""
        lo, hi = min(a, b), max(a, b)
        ks = [k for k in sorted(self.poses) if lo <= k <= hi]
        P = np.array([self.poses[k][:3, 3] for k in ks]).reshape(-1, 3)
        return float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum())

    def drift_check(self, c: LoopConstraint) -> str:
        """'' if the correction the loop asks for is within the drift the path allows, else
        'drift' (see ``LoopParams.max_drift_per_metre``)."""
        p = self.params
        if c.candidate not in self.poses or c.query not in self.poses:
            return ""
        T_map = se3_inv(self.poses[c.candidate]) @ self.poses[c.query]
        E = se3_inv(T_map) @ c.T_cand_query
        d = self.path_length(c.candidate, c.query)
        dt = float(np.linalg.norm(E[:3, 3]))
        dr = float(np.degrees(rotation_angle(E[:3, :3])))
        if dt > p.max_drift_floor_m + p.max_drift_per_metre * d or dr > p.max_rot_drift_floor_deg + p.max_rot_drift_deg_per_metre * d:
            return "drift"
        return ""

    @property
    def n_loops(self) -> int:
        return len(self.closures)

    def add_keyframe(self, kf: PlaceKeyframe, window_poses: dict[int, np.ndarray] | None = None) -> LoopClosure | None:
        t0 = time.perf_counter()
        for k, T in (window_poses or {}).items():
            if k in self.poses:
                self.poses[int(k)] = np.asarray(T, float)
        self.poses[kf.index] = np.asarray(kf.T_world_cam, float)
        constraint = self.detector.add_keyframe(kf)
        t_detect = (time.perf_counter() - t0) * 1e3
        if constraint is None:
            return None
        t1 = time.perf_counter()
        self.loop_edges.append(PoseGraphEdge(constraint.candidate, constraint.query, self.loop_measurement(constraint),
                                             LOOP))
        before = {k: T.copy() for k, T in self.poses.items()}
        order = sorted(before)
        edges = essential_graph_edges(order, before, self.detector.covisibility.pairs(), self.loop_edges,
                                      self.params.essential_min_shared)
        after, corrections, errors = self.optimise(before, edges, fixed=order[0])
        self.poses = {k: T.copy() for k, T in after.items()}
        closure = LoopClosure(constraint, corrections, before, after, errors,
                              {"detect": t_detect, "pose_graph": (time.perf_counter() - t1) * 1e3})
        self.closures.append(closure)
        return closure

    def loop_measurement(self, constraint: LoopConstraint) -> np.ndarray:
        """The loop edge's measurement: the verified rigid pose (the monocular closer: a similarity)."""
        return constraint.T_cand_query

    def optimise(self, before: dict[int, np.ndarray], edges: list[PoseGraphEdge], fixed: int):
        """SE(3) pose graph: (poses after, per-keyframe corrections, (error before, after))."""
        result = optimise_pose_graph(before, edges, self.params, fixed=fixed)
        return result.poses, pose_corrections(before, result.poses), (result.initial_error, result.final_error)
