"""Sim(3) evaluation of monocular trajectories (issue 13)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.frontend.geometry import so3_exp
from canopy.metrics import ate_sim3, evaluate_trajectory
from shared.types import Trajectory


def _ground_truth(n=80, seed=0):
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    t = np.linspace(0, 2 * np.pi, n)
    poses[:, :3, 3] = np.column_stack([5 * np.cos(t), 0.3 * np.sin(3 * t), 5 * np.sin(t)])
    for i in range(n):
        poses[i, :3, :3] = so3_exp(rng.normal(0, 0.05, 3))
    return Trajectory(np.arange(n) * 0.1, poses)


def _similar(gt: Trajectory, s: float, noise: float = 0.0, seed: int = 1) -> Trajectory:
    """gt seen through an unknown Sim(3): positions x -> R (x / s) + t (a monocular map)."""
    R = so3_exp([0.3, -1.1, 0.4])
    t = np.array([2.0, -1.0, 0.5])
    est = gt.poses.copy()
    est[:, :3, 3] = (gt.poses[:, :3, 3] / s) @ R.T + t
    est[:, :3, :3] = R @ gt.poses[:, :3, :3]
    est[:, :3, 3] += np.random.default_rng(seed).normal(0, noise, est[:, :3, 3].shape)
    return Trajectory(gt.stamps.copy(), est)


def test_sim3_recovers_the_scale_and_removes_it_from_the_error():
    gt = _ground_truth()
    est = _similar(gt, s=23.5)
    res = ate_sim3(est.poses, gt.poses)
    assert res["scale"] == pytest.approx(23.5, rel=1e-9)
    assert res["rmse"] < 1e-9
    # SE(3) alignment cannot absorb the scale: the error stays of the size of the path
    m = evaluate_trajectory(est, gt)
    assert m["ate"]["rmse"] > 1.0
    assert m["ate_sim3"]["rmse"] < 1e-9 and m["ate_sim3"]["scale"] == pytest.approx(23.5, rel=1e-9)


def test_sim3_error_is_the_noise_in_metres():
    gt = _ground_truth(400)
    est = _similar(gt, s=4.0, noise=0.01)          # 1 cm of map noise = 4 cm in metres
    res = ate_sim3(est.poses, gt.poses)
    assert res["rmse"] == pytest.approx(0.04 * np.sqrt(3), rel=0.15)
    assert res["scale"] == pytest.approx(4.0, rel=0.01)


def test_valid_mask_leaves_out_frames_before_initialisation():
    gt = _ground_truth()
    est = _similar(gt, s=2.0)
    est.poses[:10] = np.eye(4)                      # not initialised yet: start pose
    assert evaluate_trajectory(est, gt)["ate_sim3"]["rmse"] > 0.1
    valid = np.ones(len(est), bool)
    valid[:10] = False
    m = evaluate_trajectory(est, gt, valid=valid)
    assert m["n_matched"] == len(est) - 10 and m["ate_sim3"]["rmse"] < 1e-9
    with pytest.raises(ValueError, match="valid has 3 entries"):
        evaluate_trajectory(est, gt, valid=np.ones(3, bool))


def test_sim3_of_a_still_trajectory_has_no_scale():
    gt = _ground_truth(20)
    still = np.tile(np.eye(4), (20, 1, 1))
    res = ate_sim3(still, gt.poses)
    assert res["scale"] is None


def test_mono_plot_draws_the_estimate_sim3_aligned_with_its_scale(tmp_path):
    """A monocular run's plot: the scale-free estimate lands on the ground truth, scale printed."""
    import cv2

    from canopy import report

    gt = _ground_truth()
    est = _similar(gt, s=23.5)
    pos, label, text = report.align_for_plot(est, gt, align="sim3")
    assert np.abs(pos - gt.positions).max() < 1e-9
    assert "Sim(3)" in label and "scale 23.5 m/unit" in label
    assert "scale 23.5 m/unit" in text and "ATE RMSE 0.0000 m" in text
    # SE(3) cannot absorb the scale: drawn that way the estimate sits far from the truth
    pos_se3, label_se3, _ = report.align_for_plot(est, gt, align="se3")
    assert np.abs(pos_se3 - gt.positions).max() > 1.0 and "scale" not in label_se3
    png = report.plot_trajectory_png(tmp_path / "mono.png", est, gt, title="mono", align="sim3")
    assert cv2.imread(str(png)) is not None
    with pytest.raises(ValueError, match="plot alignment"):
        report.align_for_plot(est, gt, align="sim4")
    # no motion (a mono run that never initialised): no scale to fit, drawn as it is
    still = Trajectory(gt.stamps.copy(), np.tile(np.eye(4), (len(gt), 1, 1)))
    pos_still, _, text_still = report.align_for_plot(still, gt, align="sim3")
    assert np.all(pos_still == 0.0) and "needs motion" in text_still
