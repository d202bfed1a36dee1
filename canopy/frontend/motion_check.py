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
from the prediction by several times that (``track_health.ransac_departs``) is not used: the
prediction, refined on the stage-1 matches it explains, starts the local-map search instead
(ORB-SLAM's TrackWithMotionModel starts from the prediction always).
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.track_health import ransac_departs


def ransac_or_prediction(tracker, T_cw: np.ndarray | None, inliers: np.ndarray, T_pred_cw: np.ndarray,
                         X: np.ndarray, r: np.ndarray, feats: Features) -> tuple[np.ndarray | None, np.ndarray, bool]:
    """(start pose, stage-1 inlier mask, from the prediction?) for ``Tracker._track_frame``.

    RANSAC's (``T_cw``, ``inliers``) unchanged unless the motion model is valid, the pose departs
    from ``T_pred_cw`` (``ransac_departs``) and the prediction explains at least min_inliers of the
    stage-1 matches (``_start_from_prediction``): then the prediction and the matches it explains,
    with True (the caller refines from it on them first, as for ``track_from_prediction``).
    Choosing by support instead (both refined, the one more stage-1 matches or more local-map points
    support kept) was measured no better (docs/notes/s14-darkhaze.md)."""
    p = tracker.params
    if T_cw is None or not tracker._velocity_valid or not ransac_departs(T_cw, T_pred_cw, p):
        return T_cw, inliers, False
    T_p, inl_p, ok = tracker._start_from_prediction(T_pred_cw, X, feats.uv[r], inliers)
    if not ok:
        return T_cw, inliers, False
    return T_p, inl_p, True
