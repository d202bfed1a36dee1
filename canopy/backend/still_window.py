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
