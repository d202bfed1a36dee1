"""In-process lockstep reference of tracking -> local mapping -> loop closing.

``canopy.pipeline.run_sequential`` plus the loop closer after every keyframe, with no
latency: local mapping inserts the keyframe, the loop closer answers at once, and a closed
loop corrects the map before the local-map update goes back to tracking (the actors apply
the answer whenever it arrives, usually within a keyframe or two). For tests and
benchmarks of loop closing without processes.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy.backend import LocalMapper, MappingParams
from canopy.frontend import STATUS_LOST, Tracker, TrackingParams
from canopy.loop.closer import LoopCloser, LoopClosure
from canopy.loop.correction import apply_global_ba, apply_loop_correction, fuse_landmarks, refresh_update
from canopy.loop.mapping_hooks import landmark_positions, remap_landmarks
from canopy.loop.database import FeatureStats
from canopy.loop.keyframe import PlaceKeyframe, with_bow
from canopy.loop.params import LoopParams
from canopy.loop.relocalise import PlaceMemory
from shared.types import Trajectory


def place_keyframe_from_map(kf_data, mapper) -> PlaceKeyframe:
    """The loop closer's view of a keyframe local mapping has just inserted: keypoints of
    tracking's ``KeyframeData`` with the landmarks the map assigned to them."""
    rec = mapper.keyframes[kf_data.index]
    return PlaceKeyframe(index=int(kf_data.index), timestamp=float(kf_data.timestamp),
                         T_world_cam=rec.T_world_cam.copy(), uv=np.asarray(kf_data.uv, np.float64),
                         u_right=np.asarray(kf_data.u_right, np.float64), depth=np.asarray(kf_data.depth, np.float64),
                         octave=np.asarray(kf_data.octave, np.int64), descriptors=np.asarray(kf_data.descriptors, np.uint8),
                         landmark_ids=np.asarray(rec.landmark, np.int64).copy(),
                         stats=FeatureStats.of(np.zeros((0, 2)), kf_data.line_segments),
                         landmark_positions=landmark_positions(mapper, rec.landmark))


@dataclass
class LoopRunResult:
    trajectory: Trajectory
    keyframe_trajectory: Trajectory
    statuses: list[str]
    closures: list[LoopClosure] = field(default_factory=list)
    detection: dict = field(default_factory=dict)
    mapper: object = None        # the final map (for --save-map style snapshots in tests)


def run_sequential_with_loops(source, vocabulary, tracking_params: TrackingParams | None = None,
                              mapping_params: MappingParams | None = None, loop_params: LoopParams | None = None,
                              max_frames: int | None = None, on_closure=None) -> LoopRunResult:
    calib = source.calibration
    tracker = Tracker(calib, tracking_params or TrackingParams())
    mapper = LocalMapper(calib, mapping_params or MappingParams())
    closer = LoopCloser(calib, loop_params or LoopParams(), vocabulary)
    # as the tracking actor: relocalisation by database query once the motion-model bridge runs out
    tracker.attach_place_memory(PlaceMemory(calib, closer.params, vocabulary), live=True)
    n = len(source) if max_frames is None else min(len(source), max_frames)
    stamps, statuses, refs, rel, track_poses = [], [], [], [], []
    for i in range(n):
        frame = source.frame(i)
        res = tracker.track(frame)
        stamps.append(frame.timestamp)
        statuses.append(res.status)
        track_poses.append(res.T_world_cam.copy())
        if res.is_keyframe and res.keyframe is not None:
            remap_landmarks(res.keyframe, closer.alias)
            update = mapper.insert_keyframe(res.keyframe)
            kf = with_bow(place_keyframe_from_map(res.keyframe, mapper), vocabulary)
            closure = closer.add_keyframe(kf, update.keyframe_poses)
            if closure is not None:
                apply_loop_correction(mapper, closure.corrections)
                fuse_landmarks(mapper, closure.fused)
                if closer.ba_pending:  # lockstep reference: the full BA at once
                    ba = closer.global_bundle_adjust()
                    if ba is not None:
                        apply_global_ba(mapper, ba.corrections, ba.landmark_ids, ba.positions)
                refresh_update(mapper, update, closer.alias)
                update.loop_epoch = closer.epoch  # as local mapping marks a corrected update for tracking
                if on_closure is not None:
                    on_closure(closure)
            tracker.apply_map_update(update)
        refs.append(res.reference_kf_index)
        rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
    kf_final = mapper.keyframe_poses()
    poses = [kf_final[r] @ T if T is not None and r in kf_final else track_poses[i]
             for i, (T, r) in enumerate(zip(rel, refs))]
    for i, s in enumerate(statuses):
        if s == STATUS_LOST and i > 0:
            poses[i] = poses[i - 1]
    traj = Trajectory(np.asarray(stamps), np.asarray(poses).reshape(-1, 4, 4), meta={"statuses": statuses})
    s = closer.detector.stats
    return LoopRunResult(traj, mapper.keyframe_trajectory(), statuses, closer.closures,
                         {"keyframes": s.keyframes, "queries": s.queries, "candidates": s.candidates,
                          "consistent": s.consistent, "verified": s.verified, "rejected": dict(s.rejected)}, mapper)
