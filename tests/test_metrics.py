"""canopy.metrics against evo's saved results (real KITTI 00 data) and exact
generated cases."""
from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from canopy import metrics as M
from canopy.trajectory_io import read_kitti, read_tum
from shared.types import Trajectory

DATA = Path(__file__).resolve().parents[1] / "data"  # shipped with the project, see data/README.md
EVO = DATA / "evo_reference" / "test" / "data"
RES = EVO / "res_files"

# evo's numbers as quoted in data/evo_reference/PROVENANCE.md.
APE_RMSE = {"ORB": 1.3034497146, "SPTAM": 3.7384879076}
RPE_10M_RMSE = {"ORB": 0.2262613433, "SPTAM": 0.2760710904}
RES_NAME = {"ORB": "orb", "SPTAM": "sptam"}


def _evo_result(name: str) -> tuple[dict, dict, np.ndarray]:
    """(info, stats, error_array) of one evo result archive."""
    with zipfile.ZipFile(RES / f"{name}.zip") as z:
        info = json.loads(z.read("info.json"))
        stats = json.loads(z.read("stats.json"))
        with z.open("error_array.npz") as fh:
            err = np.load(fh)
            err = np.asarray(err)
    return info, stats, err


@pytest.fixture(scope="module")
def kitti00():
    gt = read_kitti(EVO / "KITTI_00_gt.txt", EVO / "KITTI_00_gt_times.txt")
    est = {n: read_kitti(EVO / f"KITTI_00_{n}.txt") for n in ("ORB", "SPTAM")}
    return gt, est


def _random_trajectory(rng, n=200, step=0.5):
    """Smooth random walk of poses (N, 4, 4)."""
    P = np.tile(np.eye(4), (n, 1, 1))
    pos = np.cumsum(rng.normal(scale=step, size=(n, 3)), axis=0)
    angles = np.cumsum(rng.normal(scale=0.05, size=(n, 3)), axis=0)
    for k in range(n):
        P[k, :3, :3] = _rot_xyz(*angles[k])
    P[:, :3, 3] = pos
    return P


def _rot_xyz(a, b, c):
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    Rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _se3(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


# --------------------------------------------------------------------------- evo reference

@pytest.mark.parametrize("name", ["ORB", "SPTAM"])
def test_ape_se3_reproduces_evo_kitti00(kitti00, name):
    gt, est = kitti00
    info, stats, err = _evo_result(f"{RES_NAME[name]}_ape")
    assert "SE(3) Umeyama alignment" in info["title"]
    res = M.ape(est[name].poses, gt.poses, align="se3")
    assert res["n"] == len(err) == 4541
    assert res["rmse"] == pytest.approx(APE_RMSE[name], abs=5e-11)
    for key in M.STAT_KEYS:
        assert res[key] == pytest.approx(stats[key], rel=1e-10, abs=1e-10), key


@pytest.mark.parametrize("name", ["ORB", "SPTAM"])
def test_rpe_10m_reproduces_evo_kitti00(kitti00, name):
    gt, est = kitti00
    info, stats, err = _evo_result(f"{RES_NAME[name]}_rpe")
    # evo settings read from the archive: delta 10 m, consecutive pairs, no alignment
    assert "delta = 10.0 (m) using consecutive pairs" in info["title"]
    assert "not aligned" in info["title"]
    res = M.rpe(est[name].poses, gt.poses, delta=10.0, unit="m", all_pairs=False)
    assert res["n"] == len(err)  # 353 (ORB) / 355 (S-PTAM) pairs, chosen on the estimate
    assert res["rmse"] == pytest.approx(RPE_10M_RMSE[name], abs=5e-11)
    for key in M.STAT_KEYS:
        assert res[key] == pytest.approx(stats[key], rel=1e-10, abs=1e-10), key


def test_kitti00_kitti_devkit_errors_are_plausible(kitti00):
    gt, est = kitti00
    res = M.kitti_relative_errors(est["ORB"].poses, gt.poses)
    assert res["lengths_used"] == list(M.KITTI_LENGTHS_M)
    assert res["n_segments"] > 3000
    # ORB-SLAM2 stereo on KITTI 00 is reported at ~0.7 % and ~0.25 deg/100 m.
    assert 0.4 < res["t_rel_percent"] < 1.0
    assert 0.1 < res["r_rel_deg_per_100m"] < 0.5


# --------------------------------------------------------------------------- association

def test_associate_synthetic_known_answer():
    a = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    b = np.array([0.004, 1.02, 1.995, 2.001, 3.5, 4.01])
    ia, ib = M.associate(a, b, max_diff=0.01)
    # 1.0 has no partner within 10 ms; 2.0 and 2.001 -> only the closest (2.001 for 2.0);
    # 4.0 <-> 4.01 is exactly at the limit (kept, <=).
    assert ia.tolist() == [0, 2, 4]
    assert ib.tolist() == [0, 3, 5]
    ia2, ib2 = M.associate(a, b, max_diff=0.001)
    assert ia2.tolist() == [2] and ib2.tolist() == [3]
    # symmetric
    jb, ja = M.associate(b, a, max_diff=0.01)
    assert ja.tolist() == [0, 2, 4] and jb.tolist() == [0, 3, 5]


def test_associate_is_one_to_one():
    a = np.array([1.000, 1.004, 1.008])
    b = np.array([1.005, 9.0, 10.0, 11.0])
    ia, ib = M.associate(a, b, max_diff=0.01)
    assert ia.tolist() == [1] and ib.tolist() == [0]


def test_associate_real_fr1_matches_evo_nearest_stamp():
    est = read_tum(EVO / "freiburg1_xyz-rgbdslam.txt")
    gt = read_tum(EVO / "freiburg1_xyz-groundtruth.txt")
    ia, ib = M.associate(est.stamps, gt.stamps, max_diff=0.01)
    # evo's matching_time_indices (shorter list against the longer one)
    ref = [(i, int(np.argmin(np.abs(gt.stamps - s)))) for i, s in enumerate(est.stamps)
           if np.min(np.abs(gt.stamps - s)) <= 0.01]
    assert np.array_equal(np.stack([ia, ib], axis=1), np.asarray(ref))
    assert len(ia) == 785
    assert np.all(np.abs(est.stamps[ia] - gt.stamps[ib]) <= 0.01)


# --------------------------------------------------------------------------- generated exact cases

def test_umeyama_recovers_known_sim3():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(3, 50))
    R = _rot_xyz(0.3, -1.1, 2.0)
    t = np.array([1.0, -2.0, 0.5])
    Y = 2.5 * R @ X + t[:, None]
    R_est, t_est, s_est = M.umeyama_alignment(X, Y, with_scale=True)
    np.testing.assert_allclose(R_est, R, atol=1e-12)
    np.testing.assert_allclose(t_est, t, atol=1e-12)
    assert s_est == pytest.approx(2.5, abs=1e-12)
    R1, t1, s1 = M.umeyama_alignment(X, R @ X + t[:, None])
    assert s1 == 1.0
    np.testing.assert_allclose(R1, R, atol=1e-12)
    np.testing.assert_allclose(t1, t, atol=1e-12)


def test_ape_of_rigidly_moved_trajectory_is_zero():
    rng = np.random.default_rng(2)
    ref = _random_trajectory(rng)
    T = _se3(_rot_xyz(0.5, 0.2, -2.5), [10.0, -3.0, 7.0])
    est = np.einsum("ij,njk->nik", T, ref)
    assert M.ape(est, ref, align="se3")["rmse"] < 1e-10
    assert M.ape(est, ref, align="none")["rmse"] > 1.0
    aligned = M.align_trajectory(est, ref)
    np.testing.assert_allclose(aligned, ref, atol=1e-10)


def test_ape_sim3_recovers_scale():
    rng = np.random.default_rng(3)
    ref = _random_trajectory(rng)
    T = _se3(_rot_xyz(-0.4, 1.0, 0.1), [1.0, 2.0, 3.0])
    est = np.einsum("ij,njk->nik", T, ref)
    est[:, :3, 3] *= 0.37  # monocular-style unknown scale
    assert M.ape(est, ref, align="sim3")["rmse"] < 1e-10
    assert M.ape(est, ref, align="se3")["rmse"] > 0.1
    np.testing.assert_allclose(M.align_trajectory(est, ref, with_scale=True), ref, atol=1e-9)


def test_ape_statistics_known_values():
    ref = np.tile(np.eye(4), (4, 1, 1))
    est = ref.copy()
    est[:, 0, 3] = [0.0, 1.0, 2.0, 3.0]  # errors 0, 1, 2, 3
    res = M.ape(est, ref, align="none")
    assert res == {"rmse": pytest.approx(np.sqrt(3.5)), "mean": 1.5, "median": 1.5,
                   "std": pytest.approx(np.sqrt(1.25)), "min": 0.0, "max": 3.0,
                   "sse": 14.0, "n": 4}


def test_rpe_identical_trajectories_is_zero():
    rng = np.random.default_rng(4)
    P = _random_trajectory(rng)
    for kwargs in ({"delta": 1}, {"delta": 5, "all_pairs": True}, {"delta": 3.0, "unit": "m"},
                   {"delta": 3.0, "unit": "m", "all_pairs": True}):
        res = M.rpe(P, P, **kwargs)
        assert res["n"] > 0
        assert res["rmse"] < 1e-12 and res["rot_max"] < 1e-6


def test_rpe_is_invariant_to_a_global_frame_and_sees_a_known_local_error():
    rng = np.random.default_rng(5)
    ref = _random_trajectory(rng, n=60)
    T = _se3(_rot_xyz(0.1, 0.2, 0.3), [5.0, 5.0, 5.0])
    est = np.einsum("ij,njk->nik", T, ref)
    assert M.rpe(est, ref, delta=1)["rmse"] < 1e-10
    # A 10 % longer step along a straight line: each 2-frame pair is 0.2 m off.
    ref2 = np.tile(np.eye(4), (10, 1, 1))
    ref2[:, 0, 3] = np.arange(10.0)  # 1 m steps along x
    est2 = ref2.copy()
    est2[:, 0, 3] = np.arange(10.0) * 1.1  # 1.1 m steps
    res = M.rpe(est2, ref2, delta=2, unit="frames")
    assert res["n"] == 4  # pairs (0,2), (2,4), (4,6), (6,8)
    assert res["rmse"] == pytest.approx(0.2) and res["rot_max"] == 0.0
    assert M.rpe(est2, ref2, delta=2, all_pairs=True)["n"] == 8


def test_rpe_rotation_angle_in_degrees():
    ref = np.tile(np.eye(4), (2, 1, 1))
    est = ref.copy()
    est[1, :3, :3] = _rot_xyz(0.0, 0.0, np.radians(7.0))
    res = M.rpe(est, ref, delta=1)
    assert res["rot_rmse"] == pytest.approx(7.0, abs=1e-12)
    assert res["rmse"] == 0.0


def test_rpe_pairs_by_path_follow_evo():
    P = np.tile(np.eye(4), (11, 1, 1))
    P[:, 0, 3] = np.arange(11.0) * 0.5  # 0.5 m steps
    # consecutive: path accumulates from pose 0; ids where it reaches 1 m: 2, 4, 6, 8, 10
    assert M.rpe_pairs(P, 1.0, "m").tolist() == [[2, 4], [4, 6], [6, 8], [8, 10]]
    # all pairs: every i with a partner 1 m (+-10 %) further along the path
    assert M.rpe_pairs(P, 1.0, "m", all_pairs=True).tolist() == [[i, i + 2] for i in range(9)]
    assert M.rpe_pairs(P, 3, "frames").tolist() == [[0, 3], [3, 6], [6, 9]]
    empty = M.rpe(P, P, delta=100.0, unit="m")
    assert empty["n"] == 0 and empty["rmse"] is None


def _straight_line(n, step):
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, 2, 3] = np.arange(n) * step  # camera driving along +z
    return P


def test_kitti_errors_of_a_one_percent_scale_error():
    gt = _straight_line(1001, 1.0)  # 1000 m
    est = gt.copy()
    est[:, :3, 3] *= 1.01
    res = M.kitti_relative_errors(est, gt)
    assert res["lengths_used"] == list(M.KITTI_LENGTHS_M)
    assert res["n_segments"] > 0
    # segments end at the first frame *beyond* L, so |d| = L + 1 m: t_rel = 1 % * (L + 1) / L
    expected = np.mean([1.0 * (L + 1.0) / L for L in M.KITTI_LENGTHS_M
                        for f in range(0, 1001, 10) if f + L + 1 <= 1000])
    assert res["t_rel_percent"] == pytest.approx(expected, rel=1e-9)
    assert res["t_rel_percent"] == pytest.approx(1.0, abs=0.01)
    assert res["r_rel_deg_per_100m"] == pytest.approx(0.0, abs=1e-9)


def test_kitti_errors_on_a_short_path_use_scaled_lengths():
    gt = _straight_line(2001, 0.01)  # 20 m
    est = gt.copy()
    est[:, :3, 3] *= 1.01
    res = M.kitti_relative_errors(est, gt)
    np.testing.assert_allclose(res["lengths_used"], np.arange(1, 9) * 2.0, rtol=1e-12)
    assert res["t_rel_percent"] == pytest.approx(1.0, abs=0.01)
    too_short = M.kitti_relative_errors(gt[:1], gt[:1])
    assert too_short["t_rel_percent"] is None and too_short["n_segments"] == 0
    static = np.tile(np.eye(4), (20, 1, 1))
    assert M.kitti_relative_errors(static, static)["t_rel_percent"] is None


def test_motion_summary_of_a_nearly_static_mav():
    P = np.tile(np.eye(4), (5, 1, 1))
    P[:, 0, 3] = [0.0, 0.001, -0.001, 0.002, 0.002]
    P[-1, :3, :3] = _rot_xyz(0.0, np.radians(0.1), 0.0)
    res = M.motion_summary(P)
    assert res["translation_m"] == pytest.approx(0.002)
    assert res["rotation_deg"] == pytest.approx(0.1, abs=1e-12)
    assert res["path_length_m"] == pytest.approx(0.001 + 0.002 + 0.003 + 0.0)
    assert res["max_displacement_m"] == pytest.approx(0.002)


def test_evaluate_trajectory_is_json_ready():
    rng = np.random.default_rng(6)
    P = _random_trajectory(rng, n=100, step=0.3)
    stamps = np.arange(100) * 0.05
    gt = Trajectory(stamps, P)
    est = Trajectory(stamps[::2] + 0.002, np.einsum("ij,njk->nik", _se3(np.eye(3), [1, 2, 3]),
                                                    P[::2]))
    res = M.evaluate_trajectory(est, gt, max_diff=0.01)
    text = json.dumps(res, allow_nan=False)
    assert json.loads(text)["n_matched"] == 50
    assert res["ate"]["rmse"] < 1e-10
    assert res["rpe_frame"]["rmse"] < 1e-10 and res["rpe_metre"]["n"] > 0
    assert res["kitti"]["t_rel_percent"] < 1e-8
    none = M.evaluate_trajectory(est, None)
    assert none["ate"] is None and none["est_motion"]["n"] == 50
    json.dumps(none, allow_nan=False)
    far = M.evaluate_trajectory(Trajectory(stamps + 100.0, P), gt)
    assert far["n_matched"] == 0 and far["ate"] is None and "no estimated stamp" in far["note"]
