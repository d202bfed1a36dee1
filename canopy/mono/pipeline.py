"""In-process lockstep run of monocular tracking -> local mapping (the mono twin of
``canopy.pipeline.run_sequential``): track a frame; hand every keyframe it produced to the
mapper and apply each update before the next frame. Frame poses are kept relative to their
reference keyframe and re-expressed with the final keyframe poses.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy.frontend import TrackingParams
from canopy.mono.mapper import MonoMapper
from canopy.pipeline import frame_poses
from canopy.mono.params import MonoParams
from canopy.mono.tracker import STATUS_INIT, STATUS_LOST, MonoTracker
from shared.types import Trajectory


@dataclass
class MonoRunResult:
    trajectory: Trajectory            # every frame (frames before initialisation: the start pose)
    keyframe_trajectory: Trajectory
    map_points: np.ndarray
    statuses: list[str]
    keyframe_indices: list[int]
    first_initialised: int | None     # frame index where the first map was made
    n_initialisations: int
    tracking_timings: list[dict[str, float]] = field(default_factory=list)
    mapping_timings: list[dict[str, float]] = field(default_factory=list)
    closures: list = field(default_factory=list)          # canopy.loop.LoopClosure, with loops on
    detection: dict = field(default_factory=dict)         # the loop detector's counts
    n_relocalised: int = 0                                # lost frames put back on the map

    @property
    def tracked_mask(self) -> np.ndarray:
        return np.array([s not in (STATUS_INIT, STATUS_LOST) for s in self.statuses], bool)


def run_mono_sequential(source, tracking_params: TrackingParams | None = None, mono_params: MonoParams | None = None,
                        max_frames: int | None = None, fast=None, vocabulary=None, loop_params=None,
                        on_closure=None) -> MonoRunResult:
    """``fast``: optional callable image -> (threshold, fallback, min_keypoints) (AFE Eq. 18-19).
    ``vocabulary``: with one (and ``mono_params.loop_enabled``), loops are closed in Sim(3)
    after every keyframe (``canopy.loop.mono.MonoLoopCloser``), the map corrected and the loop's
    two sides fused before the local-map update goes back to tracking; a lost frame tries to
    relocalise against the loop closer's keyframe database (``make_mono_relocaliser``)."""
    tracking_params = tracking_params or TrackingParams()
    mono_params = mono_params or MonoParams()
    calib = source.calibration
    tracker = MonoTracker(calib, tracking_params, mono_params)
    mapper = MonoMapper(calib, mono_params, pixel_sigma=tracking_params.pixel_sigma)
    n = len(source) if max_frames is None else min(len(source), max_frames)
    stamps, statuses, refs, rel, track_poses, kf_indices = [], [], [], [], [], []
    track_t, map_t = [], []
    first_init = None
    closer = None
    if vocabulary is not None and mono_params.loop_enabled:
        from canopy.loop.mono import MonoLoopCloser

        from canopy.loop.mono import make_mono_relocaliser

        closer = MonoLoopCloser(calib, loop_params, vocabulary, mono_params)
        tracker.relocaliser = make_mono_relocaliser(closer, mapper, vocabulary)
    for i in range(n):
        frame = source.frame(i)
        if fast is not None:
            thr, fb, mk = fast(frame.left)
            res = tracker.track(frame, fast_threshold=thr, fast_fallback=fb, fast_min_keypoints=mk)
        else:
            res = tracker.track(frame)
        track_t.append(res.timings)
        stamps.append(frame.timestamp)
        statuses.append(res.status)
        track_poses.append(res.T_world_cam.copy())
        for kf in res.keyframes:
            kf_indices.append(kf.index)
            update = mapper.insert_keyframe(kf)
            map_t.append(update.timings)
            if closer is not None:
                update = _close_loops(closer, kf, mapper, update, vocabulary, on_closure)
            tracker.apply_map_update(update)
        if res.keyframes and first_init is None and res.keyframe_reason == "initialisation":
            first_init = frame.index
        refs.append(res.reference_kf_index)
        rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
    poses = frame_poses(mapper.keyframe_poses(), refs, rel, track_poses, statuses)
    traj = Trajectory(np.asarray(stamps), np.asarray(poses).reshape(-1, 4, 4), meta={"statuses": statuses})
    detection = {}
    if closer is not None:
        d = closer.detector.stats
        detection = {"keyframes": d.keyframes, "queries": d.queries, "candidates": d.candidates,
                     "consistent": d.consistent, "verified": d.verified, "rejected": dict(d.rejected)}
    return MonoRunResult(traj, mapper.keyframe_trajectory(), mapper.map_points(), statuses, kf_indices, first_init,
                         tracker.n_initialisations, track_t, map_t, closer.closures if closer is not None else [],
                         detection, tracker.n_relocalised)


def _close_loops(closer, kf, mapper, update, vocabulary, on_closure):
    """The loop closer's step for one inserted keyframe; on a loop the map is corrected in
    Sim(3), the loop's two sides are fused, and ``update`` is re-read from the corrected map."""
    from canopy.loop.correction import refresh_update
    from canopy.loop.keyframe import with_bow
    from canopy.loop.mono import apply_sim3_correction, place_keyframe_from_mono_map

    place = with_bow(place_keyframe_from_mono_map(kf, mapper), vocabulary)
    closure = closer.add_keyframe(place, update.keyframe_poses)
    if closure is None:
        return update
    apply_sim3_correction(mapper, closure.corrections)
    mapper.fuse_loop(closure.constraint.query, closure.constraint.candidate)
    refresh_update(mapper, update)
    if on_closure is not None:
        on_closure(closure)
    return update
