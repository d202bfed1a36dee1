"""The loop closer's whole per-keyframe step, free of processes (AGRI §3.4).

``LoopCloser.add_keyframe(kf, window_poses)`` keeps its copy of the keyframe poses in
step with local BA, runs detection and verification (``LoopDetector``), and on a
verified loop optimises the essential graph in SE(3) (``optimise_pose_graph``) over all
loop edges found so far, returning the per-keyframe corrections that local mapping
applies to its map.

After a loop it also fuses the duplicated landmarks across the loop (``fuse_across_loop``)
and marks a full bundle adjustment as pending; ``global_bundle_adjust()`` runs it over all
keyframes and landmarks of its copy of the map (the actor runs it when no keyframe waits,
the in-process runner at once).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from canopy.frontend.geometry import rotation_angle, se3_inv
from canopy.loop.detector import LoopDetector
from canopy.loop.full_ba import GlobalBAResult, fuse_across_loop, resolve_array, run_ba_job
from canopy.loop.keyframe import PlaceKeyframe
from canopy.loop.params import LoopParams
from canopy.loop.pose_graph import (LOOP, PoseGraphEdge, correct_landmarks, correction_for, essential_graph_edges,
                                    optimise_pose_graph, pose_corrections)
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
    fused: dict[int, int] = field(default_factory=dict)  # duplicate landmark -> kept, across the loop


class LoopCloser:
    def __init__(self, calib: StereoCalibration, params: LoopParams | None = None, vocabulary=None):
        self.params = (params or LoopParams()).validate()
        self.detector = LoopDetector(calib, self.params, vocabulary, plausible=self.drift_check)
        self.vocabulary = vocabulary
        self.poses: dict[int, np.ndarray] = {}
        self.loop_edges: list[PoseGraphEdge] = []
        self.closures: list[LoopClosure] = []
        self.calib = calib
        # the loop closer's copy of the map points: position as local mapping last sent it,
        # the keyframe that first saw it (it moves with that keyframe's correction), fusions
        self.positions: dict[int, np.ndarray] = {}
        self.landmark_ref: dict[int, int] = {}
        self.alias: dict[int, int] = {}
        self.ba_pending = False
        self.ba_results: list[GlobalBAResult] = []
        # every answer that moves the map (pose graph, full BA) is an epoch; a keyframe message
        # sent before local mapping applied epoch e carries poses that are brought up to date
        self.epoch = 0
        self.epoch_corrections: dict[int, dict[int, np.ndarray]] = {}
        # spanning tree (ORB-SLAM): each keyframe's parent is the older keyframe it shared most
        # landmarks with when it was inserted; a keyframe a full BA did not see follows its parent
        self.parent: dict[int, int] = {}

    def _store_landmarks(self, kf: PlaceKeyframe) -> None:
        P = np.asarray(kf.landmark_positions, float).reshape(-1, 3)
        if len(P) != len(kf):
            return
        lids = resolve_array(kf.landmark_ids, self.alias)
        ok = np.flatnonzero((lids >= 0) & np.isfinite(P).all(axis=1))
        ids = lids[ok].tolist()
        # rows of one fresh copy (nothing writes a stored position in place): the dict is filled
        # at C level, in the same order as a per-landmark loop would (issue 8: loop-closer CPU)
        self.positions.update(zip(ids, P[ok]))
        ref, index = self.landmark_ref, kf.index
        ref.update((lid, index) for lid in ids if lid not in ref)

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

    def _catch_up(self, kf: PlaceKeyframe, window_poses: dict, epoch: int) -> dict:
        """Poses and landmark positions local mapping sent before it applied this closer's
        latest corrections, moved by them (each keyframe by its own or nearest older one's)."""
        from canopy.loop.mapping_hooks import catch_up_pose

        kf.T_world_cam = catch_up_pose(kf.index, kf.T_world_cam, self.epoch_corrections, epoch, self.epoch)
        window_poses = {k: catch_up_pose(int(k), T, self.epoch_corrections, epoch, self.epoch)
                        for k, T in window_poses.items()}
        P = np.asarray(kf.landmark_positions, float).reshape(-1, 3)
        if len(P) == len(kf):
            ref = np.array([self.landmark_ref.get(int(l), kf.index) for l in np.asarray(kf.landmark_ids).tolist()])
            for e in range(epoch + 1, self.epoch + 1):
                P = correct_landmarks(P, ref, self.epoch_corrections.get(e, {}))
            kf.landmark_positions = P
        return window_poses

    def _new_epoch(self, corrections: dict[int, np.ndarray]) -> None:
        self.epoch += 1
        self.epoch_corrections[self.epoch] = corrections

    def _set_parent(self, k: int) -> None:
        older = {j: n for j, n in self.detector.covisibility.neighbours(k, 1).items() if j < k}
        if older:
            self.parent[k] = max(older, key=lambda j: (older[j], j))
        else:  # shares nothing (a new map segment): the keyframe before it
            prev = [j for j in self.poses if j < k]
            if prev:
                self.parent[k] = max(prev)

    def add_known_keyframe(self, kf: PlaceKeyframe) -> None:
        """A keyframe of a loaded map: pose, landmarks and database entry, no loop query."""
        self.poses[kf.index] = np.asarray(kf.T_world_cam, float).copy()
        self._store_landmarks(kf)
        self.detector.add_known_keyframe(kf)
        self._set_parent(kf.index)

    def add_keyframe(self, kf: PlaceKeyframe, window_poses: dict[int, np.ndarray] | None = None,
                     epoch: int | None = None) -> LoopClosure | None:
        """``epoch``: the corrections local mapping had applied when it sent ``kf`` (None: all)."""
        t0 = time.perf_counter()
        window_poses = dict(window_poses or {})
        if epoch is not None and epoch < self.epoch:
            window_poses = self._catch_up(kf, window_poses, epoch)
        for k, T in window_poses.items():
            if k in self.poses:
                self.poses[int(k)] = np.asarray(T, float)
        self.poses[kf.index] = np.asarray(kf.T_world_cam, float)
        self._store_landmarks(kf)
        if self.params.verify_stereo_only:  # bearing-only keypoints: no depth (LoopParams.verify_stereo_only)
            kf.depth = np.where(np.asarray(kf.u_right) >= 0, kf.depth, -1.0)
        constraint = self.detector.add_keyframe(kf)
        self._set_parent(kf.index)
        t_detect = (time.perf_counter() - t0) * 1e3
        if constraint is None:
            return None
        return self.close_loop(constraint, t_detect)

    def close_loop(self, constraint: LoopConstraint, t_detect: float = 0.0) -> LoopClosure:
        """Correct the map for a verified loop: fusion and loop connections (ORB-SLAM order,
        ``fuse_before_pose_graph``), essential-graph optimisation, landmarks moved with their
        keyframes; a full BA is then pending."""
        t1 = time.perf_counter()
        self.loop_edges.append(PoseGraphEdge(constraint.candidate, constraint.query, self.loop_measurement(constraint),
                                             LOOP))
        before = {k: T.copy() for k, T in self.poses.items()}
        fuse_first = self.params.fuse and self.params.fuse_before_pose_graph
        fused, connections = self._fuse_before_pose_graph(constraint, before) if fuse_first else ({}, [])
        t_fuse = (time.perf_counter() - t1) * 1e3
        t1 = time.perf_counter()
        order = sorted(before)
        edges = essential_graph_edges(order, before, self.detector.covisibility.pairs(), self.loop_edges + connections,
                                      self.params.essential_min_shared)
        after, corrections, errors = self.optimise(before, edges, fixed=order[0])
        self.poses = {k: T.copy() for k, T in after.items()}
        self._new_epoch(corrections)
        self._correct_positions(corrections)
        t2 = time.perf_counter()
        if self.params.fuse and not fuse_first:
            fused = self._fuse(constraint)
            t_fuse = (time.perf_counter() - t2) * 1e3
        closure = LoopClosure(constraint, corrections, before, after, errors,
                              {"detect": t_detect, "pose_graph": (t2 - t1) * 1e3, "fuse": t_fuse,
                               "loop_connections": float(len(connections))}, fused)
        self.closures.append(closure)
        self.ba_pending = self.params.full_ba
        return closure

    def loop_measurement(self, constraint: LoopConstraint) -> np.ndarray:
        """The loop edge's measurement: the verified rigid pose (the monocular closer: a similarity)."""
        return constraint.T_cand_query

    def optimise(self, before: dict[int, np.ndarray], edges: list[PoseGraphEdge], fixed: int):
        """SE(3) pose graph: (poses after, per-keyframe corrections, (error before, after))."""
        result = optimise_pose_graph(before, edges, self.params, fixed=fixed)
        return result.poses, pose_corrections(before, result.poses), (result.initial_error, result.final_error)

    def _correct_positions(self, corrections: dict[int, np.ndarray]) -> None:
        """Landmarks move rigidly with the keyframe that first saw them (ORB-SLAM CorrectLoop)."""
        if not self.positions:
            return
        ids = list(self.positions)
        P = np.array([self.positions[i] for i in ids], float)
        ref = np.array([self.landmark_ref.get(i, min(self.poses)) for i in ids], np.int64)
        P = correct_landmarks(P, ref, corrections)
        self.positions = {i: P[j] for j, i in enumerate(ids)}

    def _loop_sides(self, c: LoopConstraint) -> tuple[list[int], list[int]]:
        cov = self.detector.covisibility
        p = self.params
        query_side = [c.query] + cov.best(c.query, p.fuse_neighbours, p.covisibility_min_shared)
        cand_side = [c.candidate] + cov.best(c.candidate, p.fuse_neighbours, p.covisibility_min_shared)
        return query_side, [k for k in cand_side if k not in set(query_side)]

    def _fuse(self, c: LoopConstraint, poses: dict[int, np.ndarray] | None = None) -> dict[int, int]:
        """Merge the duplicates of the same trees seen at both ends of the loop (query side
        seen with ``poses``, default: the closer's current poses)."""
        query_side, cand_side = self._loop_sides(c)
        fused = fuse_across_loop(self.detector.keyframes, self.poses if poses is None else poses, self.positions,
                                 query_side, cand_side, self.calib, self.params, self.alias)
        for drop in fused:
            self.positions.pop(drop, None)
        return fused

    def _fuse_before_pose_graph(self, c: LoopConstraint, before: dict[int, np.ndarray]):
        """ORB-SLAM CorrectLoop before OptimizeEssentialGraph: the query and its neighbours are
        moved rigidly to where the verified loop pose puts the query (T'_wq = T_wc T_cq), the
        candidate side's landmarks are fused into them there, and every query-side /
        candidate-side keyframe pair that now shares enough landmarks becomes a loop edge
        measured between the candidate-side pose and the corrected query-side pose (ORB-SLAM's
        LoopConnections). Returns (fusions, extra loop edges)."""
        p = self.params
        query_side, cand_side = self._loop_sides(c)
        T_wq = before[c.candidate] @ c.T_cand_query
        C = T_wq @ se3_inv(before[c.query])
        corrected = dict(before)
        for k in query_side:
            if k in before:
                corrected[k] = C @ before[k]
        fused = self._fuse(c, corrected)
        if not fused:
            return fused, []
        # landmarks of each candidate-side keyframe (after fusion), then shared counts per pair
        cand_lms = {k: set(resolve_array(self.detector.keyframes[k].landmark_ids, self.alias).tolist()) - {-1}
                    for k in cand_side if k in self.detector.keyframes}
        edges = []
        for q in query_side:
            kf = self.detector.keyframes.get(q)
            if kf is None or q not in corrected:
                continue
            mine = set(resolve_array(kf.landmark_ids, self.alias).tolist()) - {-1}
            for k, theirs in cand_lms.items():
                if k in before and len(mine & theirs) >= p.loop_connection_min_shared:
                    edges.append(PoseGraphEdge(k, q, se3_inv(before[k]) @ corrected[q], LOOP))
        return fused, edges

    def ba_job(self) -> dict | None:
        """What a full BA needs, as a snapshot (it may run in another process while this closer
        goes on taking keyframes); None when there is nothing to adjust."""
        self.ba_pending = False
        if len(self.poses) < 2:
            return None
        return {"keyframes": dict(self.detector.keyframes), "poses": {k: T.copy() for k, T in self.poses.items()},
                "positions": dict(self.positions), "calib": self.calib, "params": self.params,
                "alias": dict(self.alias), "fixed": min(self.poses), "epoch": self.epoch}

    def tree_corrections(self, corrections: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
        """``corrections`` of a full BA extended to every keyframe of this closer it did not adjust
        (inserted after its snapshot, or without landmarks): each takes the correction of its
        nearest spanning-tree ancestor that the BA adjusted (ORB-SLAM RunGlobalBundleAdjustment:
        T_child' = T_child T_parent^-1 T_parent', i.e. the parent's correction C = T_parent' T_parent^-1)."""
        out = dict(corrections)
        for k in sorted(self.poses):
            if k in out:
                continue
            chain, j = [], k
            while j not in out and j in self.parent and len(chain) < len(self.poses):
                chain.append(j)
                j = self.parent[j]
            C = out.get(j)
            if C is None:  # no adjusted ancestor (a keyframe older than the BA's gauge): nearest older
                C = correction_for(int(k), corrections)
            for c in chain or [k]:
                out[c] = C
        return out

    def accept_ba(self, result: GlobalBAResult) -> GlobalBAResult:
        """Take a full BA's answer into this closer's map: keyframes it adjusted move by its
        corrections, the others (added since it started) with their spanning-tree parent's
        (``tree_corrections``; ``result.corrections`` is extended with them, so local mapping moves
        them alike), its landmarks take its positions, the others move with their reference
        keyframe; a new epoch."""
        if self.params.full_ba_tree_corrections:
            result.corrections = self.tree_corrections(result.corrections)
        for k in list(self.poses):
            self.poses[k] = correction_for(int(k), result.corrections) @ self.poses[k]
        self._correct_positions(result.corrections)
        for lid, P in zip(result.landmark_ids.tolist(), result.positions):
            if lid in self.positions:
                self.positions[lid] = P.copy()
        self._new_epoch(result.corrections)
        self.ba_results.append(result)
        return result

    def global_bundle_adjust(self, on_iteration=None) -> GlobalBAResult | None:
        """Full BA over every keyframe and landmark of the loop closer's map (AGRI §3.4.2), at
        once (the in-process runner); returns the result for local mapping."""
        job = self.ba_job()
        if job is None:
            return None
        return self.accept_ba(run_ba_job(job, on_iteration))
