"""In-process lockstep reference of the tracking -> local mapping loop.

``run_sequential`` is what the actor system must reproduce frame for frame in lockstep
mode: track a frame; if it is a keyframe, insert it into local mapping and apply the
returned local-map update before frame ``i + 1 + map_update_lag`` (``MapUpdateSchedule``;
with a lag of 1 the actors track the next frame while the keyframe's local BA runs). Every frame's pose is stored relative to
its reference keyframe (ORB-SLAM's mlRelativeFramePoses) and re-expressed at the end with
the bundle-adjusted keyframe poses.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from canopy.backend import LocalMapper, MappingParams
from canopy.backend.final_ba import finish_map
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
    mapper: object = None                  # the LocalMapper at the end: its keyframe and landmark stores

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


class MapUpdateSchedule:
    """When tracking applies each local-map update, in lockstep (deterministic pipelining).

    The update answering the keyframe made at frame ``i`` is applied just before frame
    ``i + 1 + lag`` is tracked, never earlier even if it is already there: frames in between
    are tracked against the provisional landmarks of that keyframe (``Tracker._provisional``).
    The point of application depends only on frame indices, so every run applies the same
    update before the same frame whatever the processes' timing. ORB-SLAM's local mapping
    runs concurrently with tracking and is waited for never; a lag of 1 keeps most of that
    overlap on two cores and stays repeatable.

    Updates are held in arrival order (local mapping answers keyframes in order; with loop
    closing on it may send the last update again after a correction, which is then applied
    at the next frame)."""

    def __init__(self, lag: int):
        if lag < 0:
            raise ValueError(f"map update lag must be >= 0 frames, got {lag}")
        self.lag = int(lag)
        self._due: deque[tuple[int, int]] = deque()   # (apply before this frame, keyframe index)
        self._held: deque = deque()                  # updates received, not applied yet
        self._released = -1   # updates of keyframes up to this one are due
        self._applied = -1    # updates of keyframes up to this one are applied

    def keyframe_sent(self, keyframe_index: int, frame_index: int) -> None:
        self._due.append((frame_index + 1 + self.lag, keyframe_index))

    def hold(self, update) -> None:
        self._held.append(update)

    def _release(self, frame_index: int) -> None:
        while self._due and self._due[0][0] <= frame_index:
            self._released = max(self._released, self._due.popleft()[1])

    def missing(self, frame_index: int) -> int | None:
        """The keyframe whose update is due before ``frame_index`` but has not arrived (wait
        for it), or None."""
        self._release(frame_index)
        arrived = max([self._applied] + [u.keyframe_index for u in self._held])
        return self._released if arrived < self._released else None

    def take_due(self, frame_index: int) -> list:
        """The held updates to apply before ``frame_index``, in arrival order; updates of later
        keyframes stay held. Call when ``missing`` is None."""
        self._release(frame_index)
        out = []
        while self._held and self._held[0].keyframe_index <= self._released:
            out.append(self._held.popleft())
            self._applied = max(self._applied, out[-1].keyframe_index)
        return out


def effective_map_update_lag(lag: int, tracking_params, sensor: str = "stereo") -> int:
    """The lag a run uses: ``runtime.map_update_lag_frames``, except 0 for monocular runs (their
    initialisation and mapping expect each update before the next frame) and with line
    landmarks (KITTI 06 with lines: 0.034 m waiting for every update, 0.050 m with a lag of 1,
    worse than points alone with the lag, 0.041 m)."""
    if sensor == "mono" or getattr(tracking_params, "use_lines", False):
        return 0
    return int(lag)


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
                   initial_pose: np.ndarray | None = None, map_update_lag: int | None = None) -> SequentialResult:
    """Track every frame and map its keyframes in one process; ``map_update_lag`` (default:
    ``runtime.map_update_lag_frames``) as in the actors' lockstep (``MapUpdateSchedule``,
    ``effective_map_update_lag``)."""
    tracking_params = tracking_params or TrackingParams()
    if map_update_lag is None:
        from canopy.config import RuntimeParams
        map_update_lag = RuntimeParams().map_update_lag_frames
    schedule = MapUpdateSchedule(effective_map_update_lag(map_update_lag, tracking_params))
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
        for update in schedule.take_due(i):
            tracker.apply_map_update(update)
        res: TrackingResult = tracker.track(frame)
        track_t.append(res.timings)
        stamps.append(frame.timestamp)
        statuses.append(res.status)
        track_poses.append(res.T_world_cam.copy())
        if res.is_keyframe and res.keyframe is not None:
            kf_indices.append(res.keyframe.index)
            update = mapper.insert_keyframe(res.keyframe)
            map_t.append(update.timings)
            schedule.keyframe_sent(res.keyframe.index, i)
            schedule.hold(update)
        refs.append(res.reference_kf_index)
        rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
    finish_map(mapper)   # mapping.final_ba: the whole map adjusted once the sequence has ended
    poses = frame_poses(mapper.keyframe_poses(), refs, rel, track_poses, statuses)
    traj = Trajectory(np.asarray(stamps), np.asarray(poses).reshape(-1, 4, 4), meta={"statuses": statuses})
    return SequentialResult(traj, mapper.keyframe_trajectory(), mapper.map_points(), statuses, kf_indices,
                            track_t, map_t, tracker.n_lost, map_lines=mapper.map_lines(), mapper=mapper)

