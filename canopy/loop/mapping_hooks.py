"""Local mapping's side of loop closing: what it sends to the loop closer and how it applies
the answer. Kept here so the local-mapping actor needs only two calls."""
from __future__ import annotations

import time

import numpy as np

from canopy.loop.correction import apply_loop_correction, corrections_from_arrays, refresh_update
from protocol.messages import KeyframeData, LocalMapUpdate, LoopKeyframe, LoopResult


def loop_keyframe_message(kf: KeyframeData, mapper, update: LocalMapUpdate) -> LoopKeyframe:
    """The inserted keyframe as the loop closer needs it: tracking's keypoints with the
    landmarks the map assigned to them, its pose after local BA, and the window poses."""
    rec = mapper.keyframes[kf.index]
    return LoopKeyframe(index=int(kf.index), timestamp=float(kf.timestamp), T_world_cam=rec.T_world_cam.copy(),
                        uv=np.asarray(kf.uv, np.float32), u_right=np.asarray(kf.u_right, np.float32),
                        depth=np.asarray(kf.depth, np.float32), octave=np.asarray(kf.octave, np.int32),
                        descriptors=np.asarray(kf.descriptors, np.uint8), landmark_ids=np.asarray(rec.landmark, np.int64),
                        window_poses={int(k): np.asarray(T, float) for k, T in update.keyframe_poses.items()},
                        line_segments=np.asarray(kf.line_segments, np.float32).reshape(-1, 4),
                        sent_at=time.time())


def apply_loop_result(mapper, result: LoopResult, update: LocalMapUpdate | None) -> bool:
    """Correct the map after a closed loop and refresh ``update`` (the local map tracking
    will get) from it. Returns whether anything changed."""
    if not result.closed or len(result.keyframe_ids) == 0:
        return False
    apply_loop_correction(mapper, corrections_from_arrays(result.keyframe_ids, result.corrections))
    if update is not None:
        refresh_update(mapper, update)
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
