"""Applying a loop correction to local mapping's map (ORB-SLAM CorrectLoop, mapper side).

Works on the map's public state: ``keyframes[k].T_world_cam``, ``landmarks[id].position``
with ``.obs`` (keyframe -> keypoint), and line landmarks' ``.endpoints``. Every keyframe
moves by its correction (or that of the nearest older corrected keyframe), every landmark
rigidly with its reference keyframe, the first keyframe that observed it.
"""
from __future__ import annotations

import numpy as np

from canopy.loop.pose_graph import correction_for
from shared.arrays import unique_sorted


def corrections_from_arrays(keyframe_ids: np.ndarray, corrections: np.ndarray) -> dict[int, np.ndarray]:
    return {int(k): np.asarray(C, float) for k, C in zip(np.asarray(keyframe_ids).tolist(),
                                                         np.asarray(corrections, float).reshape(-1, 4, 4))}


def _apply(C: np.ndarray, X: np.ndarray) -> np.ndarray:
    return X @ C[:3, :3].T + C[:3, 3]


def apply_loop_correction(mapper, corrections: dict[int, np.ndarray]) -> int:
    """Move the mapper's keyframes and landmarks; returns the number of keyframes moved."""
    if not corrections:
        return 0
    for k, rec in mapper.keyframes.items():
        rec.T_world_cam = correction_for(int(k), corrections) @ rec.T_world_cam
    for lm in mapper.landmarks.values():
        if lm.obs:
            lm.position = _apply(correction_for(int(min(lm.obs)), corrections), np.asarray(lm.position, float))
    for ln in getattr(mapper, "lines", {}).values():
        if ln.obs:
            ln.endpoints = _apply(correction_for(int(min(ln.obs)), corrections), np.asarray(ln.endpoints, float))
    return len(mapper.keyframes)


def refresh_update(mapper, update, alias: dict[int, int] | None = None) -> None:
    """Re-read the positions and poses of a ``LocalMapUpdate`` from the corrected map, and
    add every keyframe pose so tracking's reference keyframe is among them."""
    ids = np.asarray(update.landmark_ids, np.int64)
    if len(ids):
        # a landmark fused away is replaced by the one it was merged into (the tracker keeps
        # seeing that tree); culled ones leave tracking's view
        if alias:
            from canopy.loop.full_ba import resolve_array
            ids = unique_sorted(resolve_array(ids, alias))
        ids = np.array([i for i in ids.tolist() if i in mapper.landmarks], np.int64)
        update.landmark_ids = ids
        update.descriptors = np.array([mapper.landmarks[i].descriptor for i in ids.tolist()], np.uint8).reshape(-1, 32)
        update.positions = np.array([mapper.landmarks[i].position for i in ids.tolist()], float).reshape(-1, 3)
    lines = getattr(mapper, "lines", {})
    line_ids = np.asarray(getattr(update, "line_ids", np.zeros(0)), np.int64)
    if len(line_ids):
        update.line_endpoints = np.array([lines[i].endpoints if i in lines else e
                                          for i, e in zip(line_ids.tolist(), np.asarray(update.line_endpoints, float))])
    update.keyframe_poses = {int(k): rec.T_world_cam.copy() for k, rec in mapper.keyframes.items()}


def fuse_landmarks(mapper, fused: dict[int, int]) -> int:
    """Merge each duplicate landmark into the one it duplicates (ORB-SLAM MapPoint::Replace):
    its observations move over (a keyframe seeing both keeps the kept one's), then it is
    deleted. Landmarks culled meanwhile or from another map segment are left alone.
    Returns the number merged."""
    n = 0
    for drop, keep in sorted(fused.items()):
        a, b = mapper.landmarks.get(int(drop)), mapper.landmarks.get(int(keep))
        if a is None or b is None or a is b or a.segment != b.segment:
            continue
        for k, i in a.obs.items():
            kf = mapper.keyframes.get(k)
            if kf is None:
                continue
            if k in b.obs:
                kf.landmark[i] = -1
            else:
                b.obs[k] = i
                kf.landmark[i] = b.id
        b.visible += a.visible
        b.found += a.found
        a.obs = {}
        del mapper.landmarks[a.id]
        n += 1
    return n


def apply_global_ba(mapper, corrections: dict[int, np.ndarray], landmark_ids: np.ndarray,
                    positions: np.ndarray) -> int:
    """A full BA's answer: keyframes move by their correction (keyframes inserted since it
    started ride with the nearest older one, ORB-SLAM's propagation of the GBA), landmarks it
    optimised take its positions, the others move with their reference keyframe.
    Returns the number of landmarks set."""
    apply_loop_correction(mapper, corrections)
    n = 0
    for lid, P in zip(np.asarray(landmark_ids, np.int64).tolist(), np.asarray(positions, float).reshape(-1, 3)):
        lm = mapper.landmarks.get(lid)
        if lm is not None:
            lm.position = P.copy()
            n += 1
    return n
