"""In-process lockstep reference of the tracking -> local mapping loop.

``run_sequential`` is what the actor system must reproduce frame for frame in lockstep
mode: track a frame; if it is a keyframe, insert it into local mapping and apply the
returned local-map update before the next frame. Every frame's pose is stored relative to
its reference keyframe (ORB-SLAM's mlRelativeFramePoses) and re-expressed at the end with
the bundle-adjusted keyframe poses.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from canopy.backend import LocalMapper, MappingParams
from canopy.frontend import STATUS_LOST, Tracker, TrackingParams, TrackingResult
from shared.types import Trajectory


@dataclass
class SequentialResult:
    trajectory: Trajectory                 # every frame, T_world_cam (lost frames: last good pose)
    keyframe_trajectory: Trajectory
    map_points: np.ndarray                 # (N,3)
    statuses: list[str]
    keyframe_indices: list[int]
    tracking_timings: list[dict[str, float]] = field(default_factory=list)
    mapping_timings: list[dict[str, float]] = field(default_factory=list)
    n_lost: int = 0
    map_lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))  # (L,2,3) endpoints A, B

    @property
    def n_frames(self) -> int:
        return len(self.statuses)

    def timing_summary(self) -> dict[str, dict[str, float]]:
        """p50 / p95 / max in ms for every stage of tracking and mapping."""
        out: dict[str, dict[str, float]] = {}
        for prefix, rows in (("tracking", self.tracking_timings), ("mapping", self.mapping_timings)):
            keys = sorted({k for r in rows for k in r})
            for k in keys:
                v = np.array([r[k] for r in rows if k in r])
                out[f"{prefix}.{k}"] = {"p50": float(np.percentile(v, 50)), "p95": float(np.percentile(v, 95)),
                                        "max": float(v.max()), "n": int(len(v))}
        return out


def frame_poses(kf_final: dict[int, np.ndarray], refs: list[int], rel: list, track_poses: list,
                statuses: list[str]) -> list[np.ndarray]:
    """Each frame's pose re-expressed with the final keyframe poses (``kf_final[ref] @ T_ref_cam``,
    the pose tracking had where its reference keyframe is gone or it had none); lost frames
    carry the last good pose forward (after correction). Shared by the stereo and monocular
    lockstep pipelines."""
    poses = [kf_final[ref] @ T_rel if T_rel is not None and ref in kf_final else track_poses[i]
             for i, (T_rel, ref) in enumerate(zip(rel, refs))]
    for i, s in enumerate(statuses):
        if s == STATUS_LOST and i > 0:
            poses[i] = poses[i - 1]
    return poses


def run_sequential(source, tracking_params: TrackingParams | None = None,
                   mapping_params: MappingParams | None = None, max_frames: int | None = None,
                   initial_pose: np.ndarray | None = None) -> SequentialResult:
    tracking_params = tracking_params or TrackingParams()
    mapping_params = mapping_params or MappingParams()
    calib = source.calibration
    tracker = Tracker(calib, tracking_params, initial_pose=initial_pose)
    mapper = LocalMapper(calib, mapping_params)
    n = len(source) if max_frames is None else min(len(source), max_frames)
    stamps, statuses, refs, rel = [], [], [], []
    track_t, map_t = [], []
    kf_indices = []
    track_poses = []
    for i in range(n):
        frame = source.frame(i)
        res: TrackingResult = tracker.track(frame)
        track_t.append(res.timings)
        stamps.append(frame.timestamp)
        statuses.append(res.status)
        track_poses.append(res.T_world_cam.copy())
        if res.is_keyframe and res.keyframe is not None:
            kf_indices.append(res.keyframe.index)
            update = mapper.insert_keyframe(res.keyframe)
            map_t.append(update.timings)
            tracker.apply_map_update(update)
        refs.append(res.reference_kf_index)
        rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
    poses = frame_poses(mapper.keyframe_poses(), refs, rel, track_poses, statuses)
    traj = Trajectory(np.asarray(stamps), np.asarray(poses).reshape(-1, 4, 4), meta={"statuses": statuses})
    return SequentialResult(traj, mapper.keyframe_trajectory(), mapper.map_points(), statuses, kf_indices,
                            track_t, map_t, tracker.n_lost, map_lines=mapper.map_lines())

