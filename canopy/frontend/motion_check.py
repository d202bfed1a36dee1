"""RANSAC's pose or the motion model's? The start of a frame's refinement on dark, hazy, noisy
frames (issue 9; docs/notes/s14-darkhaze.md).

EPnP RANSAC (AGRI §3.2.3) samples minimal sets of the stage-1 matches and keeps the pose most of
them agree with; the constant-velocity prediction is a hypothesis it never samples. When the
matches are few and half wrong (KITTI at 6 % light + haze: 40-80 stage-1 matches, 20 RANSAC
inliers) and the near points that carry them all sit at one depth (~10 m), the best minimal set
can be a yaw by theta plus a sideways shift of z * theta, which keeps those points in place; the
local-map search then looks in a small window around that pose and confirms it (KITTI 06,
g0.06-b0.06-low frame 26: 6.1 deg and 1.1 m off the prediction, 4.9 deg off ground truth; two
such frames are 9 deg of heading and most of the run's 768 mm). A car at 10 Hz changes its
per-frame motion by < 0.25 deg and 16 mm (KITTI 06 ground truth), so a RANSAC pose departing
from the prediction by several times that (``track_health.ransac_departs``) is checked against
the prediction: both are refined on the stage-1 matches (``pose.refine_pose``, the chi-square
re-classification over all of them) and the one more of them support starts the local-map
search (ORB-SLAM's TrackWithMotionModel starts from the prediction always).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.geometry import se3_inv
from canopy.frontend.stereo import StereoMatches
from canopy.frontend.track_health import ransac_departs


def local_map_support(tracker, T_cw: np.ndarray, view, feats: Features, kp_words, stereo: StereoMatches) -> int:
    """Inliers of the local-map search (stage 2 of ``Tracker._track_frame``: the landmarks in the
    frustum of ``T_cw``, the small scaled window) after the refinement from ``T_cw``."""
    p = tracker.params
    sub = np.flatnonzero(tracker._in_frustum(se3_inv(T_cw), view.ids, view.pos))
    q, r, _ = tracker._search(T_cw, view.pos[sub], view.words[sub], feats, kp_words, p.search_radius_local, scaled=True)
    if len(q) < p.min_inliers:
        return len(q)
    return int(tracker._refine(T_cw, view.pos[sub[q]], r, feats, stereo).inliers.sum())


def ransac_or_prediction(tracker, T_cw: np.ndarray | None, inliers: np.ndarray, T_pred_cw: np.ndarray,
                         X: np.ndarray, r: np.ndarray, feats: Features,
                         stereo: Callable[[], StereoMatches], view=None,
                         kp_words=None) -> tuple[np.ndarray | None, np.ndarray, bool]:
    """(start pose, stage-1 inlier mask, from the prediction?) for ``Tracker._track_frame``.

    RANSAC's (``T_cw``, ``inliers``) unchanged unless the motion model is valid, the pose departs
    from ``T_pred_cw`` (``ransac_departs``) and the prediction explains at least min_inliers of the
    stage-1 matches (``_start_from_prediction``). Then with ``ransac_deviation_compare`` both are
    refined and the prediction wins when at least as many matches support it; without it the
    prediction wins. ``stereo()`` gives the frame's stereo matches (waits for the worker; called
    only when both are refined)."""
    p = tracker.params
    if T_cw is None or not tracker._velocity_valid or not ransac_departs(T_cw, T_pred_cw, p):
        return T_cw, inliers, False
    T_p, inl_p, ok = tracker._start_from_prediction(T_pred_cw, X, feats.uv[r], inliers)
    if not ok:
        return T_cw, inliers, False
    if p.ransac_deviation_compare != "none":
        st = stereo()
        est_r = tracker._refine(T_cw, X, r, feats, st, inliers=inliers)
        est_p = tracker._refine(T_p, X, r, feats, st, inliers=inl_p)
        if p.ransac_deviation_compare == "local_map":
            n_ransac = local_map_support(tracker, est_r.T_cam_world, view, feats, kp_words, st)
            n_pred = local_map_support(tracker, est_p.T_cam_world, view, feats, kp_words, st)
        else:
            n_ransac, n_pred = int(est_r.inliers.sum()), int(est_p.inliers.sum())
        if n_pred < n_ransac:
            return T_cw, inliers, False
    return T_p, inl_p, True
