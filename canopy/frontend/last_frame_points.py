"""The last frame's stereo points as extra pose measurements (ORB-SLAM's "visual odometry" points,
Tracking::UpdateLastFrame, used here in the final motion-only refinement as well).

Why (docs/notes/s14-jitter.md): on a still camera, Canopy's per-frame pose scatters because a
tracked keypoint flips by a level pixel between frames (docs/notes/s9-jitter.md). A point that the
last frame measured and triangulated, and that this frame measures at the same pixel, says "the
camera did not move": its residual is zero at the last frame's pose, whatever the keypoint's own
error. Those terms pull the pose towards the last one wherever the keypoints did not flip, a
low-pass on the pose that the map's landmarks keep anchored. A keyframe every 3 frames gives the
same effect through landmarks triangulated 1-2 frames ago (docs/notes/s13-euroc.md), at the cost of
a local BA per keyframe; this costs one projection search and one more refinement in tracking.

Measurement model. A last-frame point X = T_last^-1 pi^-1(u', v', d') carries the last frame's
keypoint noise, so its reprojection residual in this frame has two frames' noise: sigma_vo =
factor x sigma(octave) with factor sqrt(2) for independent pixel noise of equal size.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.pose import PoseEstimate, refine_pose
from canopy.frontend.stereo import StereoMatches


def last_frame_matches(tracker, T_cw: np.ndarray, feats: Features, kp_words, used_keypoints: np.ndarray):
    """(points (K,3), keypoint indices (K,)) of the last frame's stereo points matched to this
    frame's keypoints by projection through ``T_cw`` within ``search_radius_local`` (scaled by the
    octave), leaving out keypoints in ``used_keypoints`` (already measuring a map landmark)."""
    pts, words = tracker._last_points_w, tracker._last_words
    if pts is None or len(pts) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    q, r, _ = tracker._search(T_cw, pts, words, feats, kp_words, tracker.params.search_radius_local, scaled=True)
    free = np.ones(len(feats), bool)
    free[used_keypoints] = False
    keep = free[r]
    return pts[q[keep]], r[keep]


def refine_with_last_frame(tracker, est: PoseEstimate, X: np.ndarray, r: np.ndarray, feats: Features,
                           stereo: StereoMatches, kp_words) -> PoseEstimate:
    """Re-refine ``est`` (the pose from the map matches ``X`` <-> keypoints ``r``) with the last
    frame's stereo points on keypoints no map landmark took, each at sigma x
    ``last_frame_points_sigma_factor``. The returned estimate keeps the map rows only (inliers,
    chi-square, information), at the new pose: what the keyframe decision and the map read."""
    p = tracker.params
    import os
    used = r[est.inliers] if not os.environ.get("VO_ALL") else np.zeros(0, np.int64)
    Xv, rv = last_frame_matches(tracker, est.T_cam_world, feats, kp_words, used)
    if len(rv) == 0:
        return est
    n = len(X)
    rr = np.concatenate([r, rv])
    XX = np.concatenate([np.asarray(X, float), Xv])
    meas = np.concatenate([feats.uv[rr].astype(np.float64), stereo.u_right[rr, None].astype(np.float64)], axis=1)
    sigma = tracker._sigma(feats.octave[rr]).astype(np.float64)
    sigma[n:] *= p.last_frame_points_sigma_factor
    inl0 = np.concatenate([est.inliers, np.ones(len(rv), bool)])
    both = refine_pose(est.T_cam_world, XX, meas, stereo.valid[rr], sigma, tracker.calib, p.pose_opt_rounds,
                       p.pose_opt_iterations, p.chi2_mono, p.chi2_stereo, inliers=inl0)
    tracker._n_last_frame_points = int(both.inliers[n:].sum())
    if os.environ.get("VO_DBG"):
        print("VO", n, int(est.inliers.sum()), len(rv), tracker._n_last_frame_points)
    return PoseEstimate(both.T_cam_world, both.inliers[:n], est.information, both.chi2[:n])
