"""A refined step the motion model cannot explain is solved again from the prediction (issue 9, KITTI
g1-b0.06-low seed 2 frame 29: 0.32 m short; canopy.frontend.step_check, docs/notes/s22-stepcheck.md)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.frontend import Tracker
from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import as_words
from canopy.frontend.params import TrackingParams
from canopy.frontend.pose import PoseEstimate, measurement_chi2
from canopy.frontend.step_check import local_map_pose, recheck_step, step_departs
from canopy.sources import open_source
from shared.errors import InputError

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"


def _along_axis(T_cw: np.ndarray, dz: float) -> np.ndarray:
    """``T_cw`` with its camera centre moved by ``dz`` along its own optical axis."""
    T_wc = se3_inv(T_cw)
    T_wc[:3, 3] += dz * T_wc[:3, 2]
    return se3_inv(T_wc)


def test_step_departs_by_the_camera_centre():
    T_pred = np.eye(4)
    assert step_departs(_along_axis(T_pred, -0.3), T_pred, 0.2)
    assert not step_departs(_along_axis(T_pred, -0.1), T_pred, 0.2)
    assert not step_departs(_along_axis(T_pred, -5.0), T_pred, 0.0)  # 0: off
    assert TrackingParams().step_max_deviation_m == 0.0  # off by default
    with pytest.raises(InputError, match="step_max_deviation_m"):
        TrackingParams(step_max_deviation_m=-0.1)


@pytest.fixture(scope="module")
def frame3():
    """Clean KITTI 06 frames 0-2 tracked (the velocity is valid); frame 3 extracted, its stage-1 matches,
    the prediction and the true step from frame 2."""
    src = open_source("kitti", KITTI, max_frames=4)
    p = replace(load_run_config("kitti").tracking, parallel_extraction=False, parallel_stereo=False,
                step_max_deviation_m=0.2)
    tracker = Tracker(src.calibration, p)
    for i in range(3):
        assert tracker.track(src.frame(i)).status in ("init", "ok")
    ex = tracker.extract(src.frame(3))
    feats, stereo = ex.left, tracker._stereo(ex.stereo, {})
    words = as_words(feats.descriptors)
    T_pred = se3_inv(tracker._T_last @ tracker._velocity)
    stage1 = tracker._initial_matches(T_pred, tracker._map_view(), feats, words)
    T_r, inl = tracker._ransac(3, stage1[0], feats.uv[stage1[1]])
    gt = src.ground_truth.poses
    step = se3_inv(gt[2]) @ gt[3]
    return tracker, feats, stereo, words, T_pred, stage1, T_r, inl, step


def _step_error(tracker, T_cw, true_step) -> float:
    return float(np.linalg.norm((se3_inv(tracker._T_last) @ se3_inv(T_cw))[:3, 3] - true_step[:3, 3]))


def test_a_normal_step_passes_unchanged(frame3):
    """Clean frame: the local-map solution from RANSAC's pose is within the bound; the re-check returns
    the very same solution (no second solve), a few cm from the true step."""
    tracker, feats, stereo, words, T_pred, stage1, T_r, inl, step = frame3
    view = tracker._map_view()
    first = local_map_pose(tracker, T_r, view, feats, words, lambda: stereo, stage1, inl)
    assert not step_departs(first[0].T_cam_world, T_pred, tracker.params.step_max_deviation_m)
    assert recheck_step(tracker, first, T_pred, view, feats, words, lambda: stereo, stage1, inl) is first
    assert _step_error(tracker, first[0].T_cam_world, step) < 0.05


def test_a_short_step_is_solved_again_from_the_prediction(frame3):
    """The failure of frame 29: a pose 0.4 m short along the optical axis that the local map's small
    window confirms (its inliers: the local-map matches found around it that agree with it). The
    re-check solves from the prediction, keeps the better supported solution, and its step is within
    5 cm of the truth (the short one: > 0.3 m off)."""
    tracker, feats, stereo, words, T_pred, stage1, T_r, inl, step = frame3
    view = tracker._map_view()
    p = tracker.params
    T_short = _along_axis(T_pred, -0.4)
    q, r, visible = tracker._search(T_short, view.pos, view.words, feats, words, p.search_radius_local, scaled=True)
    X, rr = view.pos[q], r
    meas = np.concatenate([feats.uv[rr], stereo.u_right[rr, None]], axis=1).astype(np.float64)
    chi2, _, _ = measurement_chi2(T_short, X, meas, stereo.valid[rr], tracker._sigma(feats.octave[rr]), tracker.calib)
    short_inl = chi2 <= np.where(stereo.valid[rr], p.chi2_stereo, p.chi2_mono)
    short = PoseEstimate(T_short, short_inl, np.eye(6), chi2)
    first = (short, (X, rr, view.ids[q], view.words[q]), view.ids[visible])
    assert _step_error(tracker, T_short, step) > 0.3
    est, (X2, r2, ids2, _), _ = recheck_step(tracker, first, T_pred, view, feats, words, lambda: stereo, stage1, inl)
    assert est is not short
    assert est.inliers.sum() > short_inl.sum()
    assert _step_error(tracker, est.T_cam_world, step) < 0.05
    assert len(X2) == len(r2) == len(ids2) == len(est.inliers)
    off = replace(p, step_max_deviation_m=0.0)
    tracker.params, saved = off, p
    try:  # the switch off: the first solution whatever it is
        assert recheck_step(tracker, first, T_pred, view, feats, words, lambda: stereo, stage1, inl) is first
    finally:
        tracker.params = saved


def test_clean_kitti_is_bit_identical_with_the_check_on():
    """Clean KITTI 06 (12 frames): every step is within the bound, the poses equal the switch-off run's."""
    src = open_source("kitti", KITTI, max_frames=12)
    base = replace(load_run_config("kitti").tracking, parallel_extraction=False, parallel_stereo=False)
    poses = []
    for p in (base, replace(base, step_max_deviation_m=0.2)):
        tracker = Tracker(src.calibration, p)
        poses.append(np.array([tracker.track(src.frame(i)).T_world_cam for i in range(len(src))]))
    assert np.array_equal(poses[0], poses[1])
