"""Local BA's window without redundant viewpoints (docs/notes/s14-jitter.md).

ORB-SLAM's local window is the new keyframe and its most covisible neighbours (LocalMapping::
LocalBundleAdjustment); every other keyframe observing their landmarks enters fixed. On a still
camera every keyframe sees the same landmarks from the same place, so the window fills with
keyframes whose poses BA has nothing to refine with: a neighbour whose view is within
``mapping.window_min_view_change_px`` (at the new keyframe's median stereo depth) of a keyframe
already in the window adds no geometry. It is left out of the optimised set;
its observations still constrain the landmarks as a fixed keyframe, which is what averages a
still camera's keypoint noise. A moving camera's neighbours differ by more and fill the window as before.
"""
from __future__ import annotations

import numpy as np

# A viewpoint change (dt, dtheta) moves a point at depth z in the image by about fx |dt| / z (parallax)
# plus fx |dtheta| (rotation). Below the keypoint noise (pixel sigma 1 at octave 0, ORB-SLAM's) two
# views differ by less than their measurements do: the second adds no geometry, only another draw
# of the noise.
def view_change_px(T_a: np.ndarray, T_b: np.ndarray, depth: float, fx: float) -> float:
    """Image motion (px) between camera poses ``T_a`` and ``T_b`` (4x4, world from camera) for points at
    ``depth`` (m): fx |t_a - t_b| / depth + fx * angle(R_a^T R_b)."""
    if not (np.isfinite(depth) and depth > 0):
        raise ValueError(f"view_change_px: depth must be finite and > 0, got {depth}")
    dt = float(np.linalg.norm(np.asarray(T_a, float)[:3, 3] - np.asarray(T_b, float)[:3, 3]))
    R = np.asarray(T_a, float)[:3, :3].T @ np.asarray(T_b, float)[:3, :3]
    angle = float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
    return fx * dt / depth + fx * angle


def median_depth(depths: np.ndarray) -> float | None:
    """Median of the positive finite ``depths`` (m), None when there is none."""
    d = np.asarray(depths, float).reshape(-1)
    d = d[np.isfinite(d) & (d > 0)]
    return float(np.median(d)) if len(d) else None


def keyframe_depths(rec, bf: float) -> np.ndarray:
    """Stereo depths bf / (u_left - u_right) of a keyframe's keypoints with a right match (others 0)."""
    disp = rec.uv[:, 0] - rec.u_right
    ok = (rec.u_right >= 0) & (disp > 0)
    return np.where(ok, bf / np.where(ok, disp, 1.0), 0.0)


def window_neighbours(mapper, rec, neigh: list[int]) -> list[int]:
    """The neighbours (sorted strongest first) that join ``rec`` in the optimised window: the first
    ``window_size - 1``, skipping those whose view is within ``window_min_view_change_px`` of a keyframe
    already chosen. With the option 0 (off), or no stereo depth, the first ``window_size - 1``."""
    p = mapper.params
    n = p.window_size - 1
    if p.window_min_view_change_px <= 0:
        return neigh[:n]
    z = median_depth(keyframe_depths(rec, mapper.calib.bf))
    if z is None:
        return neigh[:n]
    chosen, poses = [], [rec.T_world_cam]
    for k in neigh:
        if len(chosen) == n:
            break
        T = mapper.keyframes[k].T_world_cam
        if min(view_change_px(T, P, z, mapper.calib.fx) for P in poses) >= p.window_min_view_change_px:
            chosen.append(k)
            poses.append(T)
    return chosen


def bounded_fixed(mapper, rec, local: list[int], fixed: list[int]) -> list[int]:
    """Local BA's fixed keyframes, at most ``mapping.window_max_fixed`` of them (0: all, ORB-SLAM's):
    the ones observing the most of the local keyframes' landmarks (newest first among equals), and the
    segment's first keyframe where it is among them (it holds the gauge). On a still camera every
    keyframe observes every local landmark, so the fixed set and BA's edges would grow with each
    keyframe (docs/notes/s15-stillcost.md); the best-covisible bound is ORB-SLAM's for its searches
    (GetBestCovisibilityKeyFrames)."""
    n = mapper.params.window_max_fixed
    if n <= 0 or len(fixed) <= n:
        return fixed
    first = mapper._segment_first[rec.segment]
    seen = np.concatenate([mapper.keyframes[k].landmark for k in local])
    seen = seen[seen >= 0]
    counts = {}
    for k in fixed:
        lm = mapper.keyframes[k].landmark
        counts[k] = int(np.count_nonzero(np.isin(lm[lm >= 0], seen, assume_unique=False)))
    keep = set(sorted(fixed, key=lambda k: (-counts[k], -k))[:n])
    if first in fixed:
        keep.add(first)
    return sorted(keep)


def descriptor_observations(obs: dict[int, int], n: int) -> dict[int, int]:
    """The newest ``n`` of a landmark's observations (keyframe -> keypoint row, insertion order) for
    its distinctive descriptor (0: all, ORB-SLAM's ComputeDistinctiveDescriptors). The median-distance
    minimiser costs O(n^2) per landmark, and on a still camera n grows with every keyframe."""
    if n <= 0 or len(obs) <= n:
        return obs
    items = list(obs.items())[-n:]
    return dict(items)


def depth_constrained(mapper, lm_ids: list[int], e_kf: np.ndarray, e_lm: np.ndarray, e_kp: np.ndarray):
    """Local BA's landmarks and edges restricted to landmarks with a stereo observation among the edges.

    When BA sees only part of a landmark's observations (``window_max_fixed``, keyframe culling), a
    landmark made from stereo in a keyframe left out may keep only left-image (mono) observations from
    nearly one viewpoint: on a still camera nothing fixes its depth, and LM walks it out along the ray
    (EuRoC g1-b0.06-low with 8 fixed keyframes: landmarks at 0.2-5 km by frame 39). Tracking keeps such
    a point as an inlier at any translation, and EPnP's final fit over RANSAC's inliers, whose control
    points it dominates, returns poses 0.3-3 m off (docs/notes/s15-stillcost.md). Those landmarks stay
    where they are. Returns (lm_ids, e_kf, e_lm, e_kp) as ``MapStoreAccess._observation_edges``."""
    if not len(e_kf):
        return lm_ids, e_kf, e_lm, e_kp
    kf_ids = np.unique(e_kf)
    table = np.concatenate([mapper.keyframes[k].u_right for k in kf_ids.tolist()])
    start = np.zeros(int(kf_ids[-1]) + 1, np.int64)
    start[kf_ids] = np.cumsum([0] + [len(mapper.keyframes[k].u_right) for k in kf_ids[:-1].tolist()])
    stereo = table[start[e_kf] + e_kp] >= 0
    lm_arr = np.asarray(lm_ids, np.int64)
    has = np.zeros(len(lm_arr), bool)
    has[np.searchsorted(lm_arr, e_lm[stereo])] = True
    keep_lm = lm_arr[has]
    keep = has[np.searchsorted(lm_arr, e_lm)]
    return keep_lm.tolist(), e_kf[keep], e_lm[keep], e_kp[keep]
