"""Local mapping's side of loop closing: what it sends to the loop closer and how it applies
the answer. Kept here so the local-mapping actor needs only two calls."""
from __future__ import annotations

import time

import numpy as np

from canopy.loop.correction import (apply_global_ba, apply_loop_correction, corrections_from_arrays, fuse_landmarks,
                                    refresh_update)
from protocol.messages import KeyframeData, LocalMapUpdate, LoopKeyframe, LoopResult


def loop_keyframe_message(kf: KeyframeData, mapper, update: LocalMapUpdate) -> LoopKeyframe:
    """The inserted keyframe as the loop closer needs it: tracking's keypoints with the
    landmarks the map assigned to them, its pose after local BA, and the window poses."""
    rec = mapper.keyframes[kf.index]
    return LoopKeyframe(landmark_positions=landmark_positions(mapper, rec.landmark, update), index=int(kf.index), timestamp=float(kf.timestamp), T_world_cam=rec.T_world_cam.copy(),
                        uv=np.asarray(kf.uv, np.float32), u_right=np.asarray(kf.u_right, np.float32),
                        depth=np.asarray(kf.depth, np.float32), octave=np.asarray(kf.octave, np.int32),
                        descriptors=np.asarray(kf.descriptors, np.uint8), landmark_ids=np.asarray(rec.landmark, np.int64),
                        window_poses={int(k): np.asarray(T, float) for k, T in update.keyframe_poses.items()},
                        line_segments=np.asarray(kf.line_segments, np.float32).reshape(-1, 4),
                        sent_at=time.time())


def landmark_positions(mapper, landmark_ids: np.ndarray, update: LocalMapUpdate | None = None) -> np.ndarray:
    """(N,3) world positions of the landmarks a keyframe's keypoints observe (NaN: none).

    ``update``: the local map just built from this same map state (sorted ids, positions copied
    from the landmarks): the keyframe is in its window, so its landmarks are looked up there in
    one ``searchsorted`` (a dict lookup and a row write per keypoint cost ~0.8 ms per KITTI
    keyframe on local mapping's thread); any id it lacks is read from the map as before."""
    ids = np.asarray(landmark_ids, np.int64)
    out = np.full((len(ids), 3), np.nan)
    rest = ids >= 0
    if update is not None and len(update.landmark_ids) and rest.any():
        known = np.asarray(update.landmark_ids, np.int64)
        j = np.minimum(np.searchsorted(known, ids), len(known) - 1)
        hit = rest & (known[j] == ids)
        out[hit] = np.asarray(update.positions, float).reshape(-1, 3)[j[hit]]
        rest &= ~hit
    for i in np.flatnonzero(rest).tolist():
        lm = mapper.landmarks.get(int(ids[i]))
        if lm is not None:
            out[i] = lm.position
    return out


def remap_landmarks(kf: KeyframeData, alias: dict[int, int]) -> None:
    """A keyframe tracked against landmarks since fused: its keypoints observe the kept ones."""
    if alias and len(kf.landmark_ids):
        from canopy.loop.full_ba import resolve_array
        kf.landmark_ids = resolve_array(kf.landmark_ids, alias)


def apply_loop_result(mapper, result: LoopResult, update: LocalMapUpdate | None,
                      alias: dict[int, int] | None = None) -> bool:
    """Correct the map after a closed loop (pose-graph correction, then landmark fusion) or
    after a full BA, and refresh ``update`` (the local map tracking will get) from it.
    Fusions are added to ``alias``. Returns whether anything changed."""
    if len(result.keyframe_ids) == 0 or not (result.closed or result.global_ba):
        return False
    corrections = corrections_from_arrays(result.keyframe_ids, result.corrections)
    if result.global_ba:
        apply_global_ba(mapper, corrections, result.landmark_ids, result.landmark_positions)
    else:
        apply_loop_correction(mapper, corrections)
    fused = {int(a): int(b) for a, b in np.asarray(result.fused, np.int64).reshape(-1, 2).tolist()}
    if fused:
        fuse_landmarks(mapper, fused)
        if alias is not None:
            alias.update(fused)
    if update is not None:
        refresh_update(mapper, update, alias)
    return True


def catch_up_pose(index: int, T_world_cam: np.ndarray, epoch_corrections: dict[int, dict], from_epoch: int,
                  to_epoch: int) -> np.ndarray:
    """The pose of a keyframe tracking computed before loop corrections ``from_epoch+1 ..
    to_epoch`` reached it, moved by each of them (its own or its nearest older keyframe's)."""
    from canopy.loop.pose_graph import correction_for

    T = np.asarray(T_world_cam, float)
    for e in range(from_epoch + 1, to_epoch + 1):
        corr = epoch_corrections.get(e)
        if corr:
            T = correction_for(int(index), corr) @ T
    return T
