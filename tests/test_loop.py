"""Loop closing building blocks: keyframe database, geometric verification on real EuRoC
loop pairs (Kimera's LCD test images), SE(3) pose graph with exact ground truth."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.frontend.geometry import rotation_angle, se3_exp, se3_inv
from canopy.loop import (LOOP, ODOMETRY, FeatureStats, KeyframeDatabase, LoopParams, PoseGraphEdge, combined_score,
                         correct_landmarks, describe_stereo_pair, l1_score, optimise_pose_graph, pose_corrections,
                         verify_candidate)
from canopy.loop.pose_graph import relative
from canopy.sources.base import read_grey
from canopy.sources.euroc import _CameraModel
from shared.geometry import quat_wxyz_to_rot
from shared.types import StereoCalibration

DATA = Path(__file__).resolve().parents[1] / "data"
KIMERA = DATA / "kimera_lcd"
VICON2GT = DATA / "euroc_v101_micro" / "gt_sources" / "openvins_V1_01_easy_vicon2gt.csv"


# ----------------------------------------------------------------------------- database
def _random_bow(rng, n_words=200, size=40):
    words = rng.choice(n_words, size=size, replace=False)
    w = rng.random(size)
    return {int(k): float(v) for k, v in zip(words, w / w.sum())}


def test_l1_score_is_dbow2_score():
    rng = np.random.default_rng(1)
    a, b = _random_bow(rng), _random_bow(rng)
    dense = np.zeros((2, 200))
    for i, v in enumerate((a, b)):
        dense[i, list(v)] = list(v.values())
    assert l1_score(a, b) == pytest.approx(1 - 0.5 * np.abs(dense[0] - dense[1]).sum())
    assert l1_score(a, a) == pytest.approx(1.0)
    assert l1_score({1: 1.0}, {2: 1.0}) == 0.0


def test_database_query_finds_the_place_and_respects_bar_exclusion_and_removal():
    rng = np.random.default_rng(2)
    db = KeyframeDatabase()
    bows = {k: _random_bow(rng, n_words=5000, size=300) for k in range(30)}
    for k, v in bows.items():
        db.add(k, v)
    # a revisit of keyframe 7: most of its words with perturbed weights, some new ones
    q = {w: v * rng.uniform(0.8, 1.2) for w, v in list(bows[7].items())[:240]}
    q.update({10000 + i: 0.002 for i in range(30)})
    s = sum(q.values())
    q = {w: v / s for w, v in q.items()}
    res = db.query(q)
    assert res[0].keyframe == 7 and res[0].score > 0.5
    assert res[0].score == pytest.approx(l1_score(q, bows[7]))
    assert all(c.score < 0.2 for c in res[1:])
    assert db.query(q, min_score=0.5) == res[:1]
    assert 7 not in [c.keyframe for c in db.query(q, exclude={7})]
    db.remove(7)
    assert 7 not in [c.keyframe for c in db.query(q)] and len(db) == 29


def test_combined_score_leans_on_the_feature_type_the_images_have():
    pts_only = FeatureStats(n_points=500, n_lines=0, spread_points=200.0)
    assert combined_score(0.3, 0.9, pts_only, pts_only) == 0.3
    lines_rich = FeatureStats(n_points=50, n_lines=150, spread_points=30.0, spread_lines=200.0)
    s = combined_score(0.1, 0.8, lines_rich, lines_rich)
    assert 0.6 < s < 0.8  # mostly the line score: lines are 3/4 of the features and spread wider


# ----------------------------------------------------------------------------- verification
def _kimera():
    """Rectified Kimera LCD pairs and ground truth for the rectified left camera."""
    c0, c1 = _CameraModel(KIMERA / "sensorLeft.yaml"), _CameraModel(KIMERA / "sensorRight.yaml")
    size = (c0.width, c0.height)
    T_c1_c0 = np.linalg.inv(np.linalg.inv(c0.T_B_S) @ c1.T_B_S)
    R1, R2, P1, P2, *_ = cv2.stereoRectify(c0.K, c0.D, c1.K, c1.D, size, T_c1_c0[:3, :3].copy(),
                                           T_c1_c0[:3, 3].reshape(3, 1).copy(), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    maps = [cv2.initUndistortRectifyMap(c.K, c.D, R, P, size, cv2.CV_32FC1) for c, R, P in ((c0, R1, P1), (c1, R2, P2))]
    calib = StereoCalibration(P1[0, 0], P1[1, 1], P1[0, 2], P1[1, 2], -P2[0, 3] / P2[0, 0], size[0], size[1])
    T_body_rect = c0.T_B_S.copy()
    T_body_rect[:3, :3] = c0.T_B_S[:3, :3] @ R1.T
    stamps = {}
    for line in (KIMERA / "gt_euroc_V1_01_easy_for_images.csv").read_text().splitlines():
        if not line.startswith("#"):
            f = line.split(",")
            stamps[int(f[0][len("left_img_")])] = f[1]
    # ground truth: the vicon2gt re-estimate shipped with the EuRoC micro set (the original
    # EuRoC estimate in the Kimera csv disagrees with it by 5.5 cm / 2.1 deg on the revisit pair)
    gt = {}
    for line in VICON2GT.read_text().splitlines():
        f = line.split(",")
        for i, s in stamps.items():
            if f[0] == s:
                v = np.array(f[1:8], float)
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = quat_wxyz_to_rot(v[3:7]), v[:3]
                gt[i] = T @ T_body_rect
    kfs = {}
    for i in range(4):
        left = cv2.remap(read_grey(KIMERA / f"left_img_{i}.png"), *maps[0], cv2.INTER_LINEAR)
        right = cv2.remap(read_grey(KIMERA / f"right_img_{i}.png"), *maps[1], cv2.INTER_LINEAR)
        kfs[i] = describe_stereo_pair(i, 0.0, left, right, calib)
    return calib, kfs, gt


@pytest.fixture(scope="module")
def kimera():
    return _kimera()


@pytest.mark.parametrize("query, match", [(1, 0), (3, 2)])
def test_verification_recovers_relative_pose_of_real_loop_pairs(kimera, query, match):
    calib, kfs, gt = kimera
    v = verify_candidate(kfs[query], kfs[match], calib, LoopParams())
    assert v.constraint is not None, v.reason
    E = se3_inv(se3_inv(gt[match]) @ gt[query]) @ v.constraint.T_cand_query
    assert np.linalg.norm(E[:3, 3]) < 0.05
    assert np.degrees(rotation_angle(E[:3, :3])) < 2.0


@pytest.mark.parametrize("query, other", [(1, 2), (1, 3), (0, 2)])
def test_verification_rejects_different_places(kimera, query, other):
    calib, kfs, _ = kimera
    v = verify_candidate(kfs[query], kfs[other], calib, LoopParams())
    assert v.constraint is None and v.reason != "ok"


# ----------------------------------------------------------------------------- pose graph
def _circle(n, radius=10.0):
    poses = {}
    for k in range(n):
        a = 2 * np.pi * k / n
        T = se3_exp(np.array([0, 0, 0, 0, a, 0]))
        T[:3, 3] = [radius * np.cos(a), 0.0, radius * np.sin(a)]
        poses[k] = T
    return poses


def test_pose_graph_recovers_exact_poses_from_drifted_start():
    gt = _circle(200)
    drift = se3_exp(np.array([0.002, -0.001, 0.003, 0.001, 0.002, -0.001]))
    est = {0: gt[0]}
    for k in range(1, 200):
        est[k] = est[k - 1] @ relative(gt[k - 1], gt[k]) @ drift
    edges = [PoseGraphEdge(k - 1, k, relative(gt[k - 1], gt[k]), ODOMETRY) for k in range(1, 200)]
    edges.append(PoseGraphEdge(0, 199, relative(gt[0], gt[199]), LOOP))
    res = optimise_pose_graph(est, edges, LoopParams())
    assert max(np.linalg.norm(est[k][:3, 3] - gt[k][:3, 3]) for k in gt) > 1.0
    assert max(np.linalg.norm(res.poses[k][:3, 3] - gt[k][:3, 3]) for k in gt) < 1e-6
    assert res.final_error < 1e-9 < res.initial_error


def test_loop_edge_spreads_drift_and_landmarks_follow_their_keyframe():
    """Odometry with a constant bias (the map's drift) + one exact loop edge: the loop closes
    and the worst position error drops by far; a landmark moves rigidly with its keyframe."""
    n = 120
    gt = _circle(n)
    bias = se3_exp(np.array([0.0, 0.0, 0.004, 0.0005, 0.0, 0.0]))
    odo = {k: relative(gt[k - 1], gt[k]) @ bias for k in range(1, n)}
    est = {0: gt[0]}
    for k in range(1, n):
        est[k] = est[k - 1] @ odo[k]
    edges = [PoseGraphEdge(k - 1, k, odo[k], ODOMETRY) for k in range(1, n)]
    edges.append(PoseGraphEdge(0, n - 1, relative(gt[0], gt[n - 1]), LOOP))
    res = optimise_pose_graph(est, edges, LoopParams())
    err_before = max(np.linalg.norm(est[k][:3, 3] - gt[k][:3, 3]) for k in gt)
    err_after = max(np.linalg.norm(res.poses[k][:3, 3] - gt[k][:3, 3]) for k in gt)
    assert err_after < 0.15 * err_before
    end = np.linalg.norm(res.poses[n - 1][:3, 3] - gt[n - 1][:3, 3])
    assert end < 0.05 * np.linalg.norm(est[n - 1][:3, 3] - gt[n - 1][:3, 3])
    C = pose_corrections(est, res.poses)
    X_cam = np.array([[0.5, -0.2, 4.0]])
    X_before = X_cam @ est[80][:3, :3].T + est[80][:3, 3]
    X_after = correct_landmarks(X_before, np.array([80]), C)
    np.testing.assert_allclose(X_after, X_cam @ res.poses[80][:3, :3].T + res.poses[80][:3, 3], atol=1e-9)


# ----------------------------------------------------------------------------- generated revisit
@pytest.fixture(scope="module")
def day_loop_views():
    """Four rendered stereo views of the generated day-loop (exact poses): near the start, its
    revisit after one lap, and two other places (other rows of the same-looking orchard)."""
    from canopy.synthetic import SequenceGenerator, resolve_params

    gen = SequenceGenerator(resolve_params("day-loop"), seed=0)
    P = np.array([T[:3, 3] for T in gen.track.poses])
    half = len(P) // 2
    revisit = half + int(np.argmin(np.linalg.norm(P[half:] - P[5], axis=1)))
    views = {}
    for i in (5, revisit, 300, 600):
        left, right, _ = gen.stereo(i)
        views[i] = describe_stereo_pair(i, 0.0, left, right, gen.calibration)
    return gen, revisit, views


def test_generated_revisit_verified_with_exact_relative_pose(day_loop_views):
    gen, revisit, views = day_loop_views
    assert revisit > 900  # after one lap (72 m), not a neighbour in time
    v = verify_candidate(views[revisit], views[5], gen.calibration, LoopParams())
    assert v.constraint is not None, v.reason
    E = se3_inv(se3_inv(gen.track.poses[5]) @ gen.track.poses[revisit]) @ v.constraint.T_cand_query
    assert np.linalg.norm(E[:3, 3]) < 0.01
    assert np.degrees(rotation_angle(E[:3, :3])) < 0.2
    for other in (300, 600):  # other rows: look alike, are not the place
        assert verify_candidate(views[revisit], views[other], gen.calibration, LoopParams()).constraint is None


def test_generated_revisit_is_the_best_database_match(day_loop_views):
    """Place recognition with the shipped vocabulary: of the stored views, the revisit's
    best-scoring keyframe is the place it revisits, well above the look-alike rows."""
    from canopy.loop import with_bow
    from canopy.loop.vocabulary import load_vocabulary

    gen, revisit, views = day_loop_views
    voc = load_vocabulary()
    db = KeyframeDatabase()
    for i in (5, 300, 600):
        kf = with_bow(views[i], voc)
        db.add(i, kf.bow, stats=kf.stats)
    q = with_bow(views[revisit], voc)
    res = db.query(q.bow, stats=q.stats)
    assert res[0].keyframe == 5
    assert res[0].score > 1.5 * max(c.score for c in res[1:])


@pytest.mark.parametrize("spacing", [1, 10**7])   # dense keyframe indices (bins) and sparse ones (sort)
def test_database_scores_equal_the_pairwise_l1_score(spacing):
    from canopy.place import Vocabulary

    rng = np.random.default_rng(11)

    def bow():
        words = rng.choice(400, size=int(rng.integers(5, 60)), replace=False)
        v = rng.random(len(words))
        return dict(zip(words.tolist(), (v / v.sum()).tolist()))

    db, stored = KeyframeDatabase(), {}
    for i in range(200):   # > MIN_MERGE postings: merged arrays and a tail both hold keyframes
        k = 3 + i * spacing
        stored[k] = bow()
        db.add(k, stored[k])
    for k in list(stored)[5:15] + list(stored)[-3:]:
        db.remove(k)
        del stored[k]
    for _ in range(5):
        q = bow()
        got = db.scores(q)
        want = {k: Vocabulary.score(q, b) for k, b in stored.items() if set(q) & set(b)}
        assert sorted(got) == sorted(want)
        for k, (s, common) in got.items():
            assert s == pytest.approx(want[k], abs=1e-12) and common == len(set(q) & set(stored[k]))
