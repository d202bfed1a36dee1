"""A refined pose whose step the motion model cannot explain: solve the frame again from the
prediction (issue 9, KITTI's swinging cells; docs/notes/s22-stepcheck.md).

``local_map_pose`` is stage 2 of ``Tracker._track_frame`` (ORB-SLAM's TrackLocalMap): every
local-map point in the frustum projected through the starting pose, matched within a small window
(``search_radius_local`` px at octave 0), and the motion-only refinement on those matches (on the
stage-1 matches when the search finds too few). The window is what makes a wrong start stick: a
start 0.4 m short along the optical axis on KITTI (points at 7-28 m) moves the projections of the
image's outer points by a few pixels only, the search still finds matches there (197 inliers of 331
on g1-b0.06-low seed 2 frame 29, as many as its neighbours), and the refinement converges among
them to a pose 0.32 m short whose own covariance says 8 mm (38 sigma from the prediction).

``recheck_step``: a car at 10 Hz changes its per-frame motion by < 0.25 deg / 16 mm (KITTI 06
ground truth), so a refined camera centre more than ``step_max_deviation_m`` from the constant-
velocity prediction is either a real change of motion or a wrong minimum. The frame is solved once
more from the prediction (ORB-SLAM's TrackWithMotionModel: the prediction, refined on the stage-1
matches it explains, starts the local-map search). When the two solutions are different minima
(centres more than half the bound apart) the one more local-map points support (more inliers) is
kept; when both starts reach one minimum the first stays as it was (a real change of motion, or the
optical-axis noise of far, noisy points: on KITTI g0.06-b0-high seed 0 both solutions of frame 19
lie 0.32 m from the prediction, 1 cm apart, and swapping them made the run 62 -> 85 mm by chaos).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.geometry import se3_inv
from canopy.frontend.map_view import MapView
from canopy.frontend.track_health import motion_deviation


def local_map_pose(tracker, T_cw: np.ndarray, view: MapView, feats: Features, kp_words, stereo_of: Callable,
                   stage1: tuple, inliers: np.ndarray, line_obs=None, n_lines: int = 0):
    """Stage 2 from ``T_cw``: (estimate, (X, r, ids, words) it was refined on, ids of the local-map
    points in view). ``stage1``: the (X, r, ids, words) of stage 1 with their ``inliers``, refined on
    when the local map gives fewer than min_inliers; ``stereo_of()`` returns the frame's stereo
    matches (waits for the worker: called after the search, which does not need them)."""
    p = tracker.params
    sub = np.flatnonzero(tracker._in_frustum(se3_inv(T_cw), view.ids, view.pos))
    q2, r2, in_view = tracker._search(T_cw, view.pos[sub], view.words[sub], feats, kp_words,
                                      p.search_radius_local, scaled=True)
    q2 = sub[q2]
    visible_ids = view.ids[sub[in_view]]
    stereo = stereo_of()
    est, used = None, stage1
    if len(q2) + n_lines >= p.min_inliers:
        est = tracker._refine(T_cw, view.pos[q2], r2, feats, stereo, line_obs=line_obs)
        if tracker._n_support(est) >= p.min_inliers:
            used = (view.pos[q2], r2, view.ids[q2], view.words[q2])
        else:
            est = None
    if est is None:
        X, r = stage1[0], stage1[1]
        est = tracker._refine(T_cw, X, r, feats, stereo, inliers=inliers, line_obs=line_obs)
    return est, used, visible_ids


def step_departs(T_cw: np.ndarray, T_pred_cw: np.ndarray, max_m: float) -> bool:
    """Does the camera centre of ``T_cw`` lie more than ``max_m`` from the prediction's (0: off)?"""
    return max_m > 0 and motion_deviation(T_cw, T_pred_cw)[0] > max_m


def recheck_step(tracker, first: tuple, T_pred_cw: np.ndarray, view: MapView, feats: Features, kp_words,
                 stereo_of: Callable, stage1: tuple, stage1_inliers: np.ndarray) -> tuple:
    """``first`` = ``local_map_pose``'s result for the frame; the same for the solve from the
    prediction when ``first``'s pose departs from it by more than ``step_max_deviation_m`` and the
    re-solve is another minimum with more support, else ``first`` unchanged (module docstring)."""
    est = first[0]
    if est is None or not step_departs(est.T_cam_world, T_pred_cw, tracker.params.step_max_deviation_m):
        return first
    X, r = stage1[0], stage1[1]
    T_p, inl_p, ok = tracker._start_from_prediction(T_pred_cw, X, feats.uv[r], stage1_inliers)
    if not ok:
        return first
    start = tracker._refine(T_p, X, r, feats, stereo_of(), inliers=inl_p)
    second = local_map_pose(tracker, start.T_cam_world, view, feats, kp_words, stereo_of, stage1, inl_p)
    if not step_departs(second[0].T_cam_world, est.T_cam_world, 0.5 * tracker.params.step_max_deviation_m):
        return first  # both starts reach one minimum: a real change of motion, or depth noise; the first stays
    return second if tracker._n_support(second[0]) > tracker._n_support(est) else first
