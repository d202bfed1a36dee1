"""Monocular loop closing in Sim(3) (issue 13): Horn/Umeyama Sim(3) RANSAC, the Sim(3) pose
graph, PnP + Sim(3) verification and relocalisation on rendered views of the generated
day-loop with exact poses, and the map correction by similarities."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from canopy.frontend.geometry import rotation_angle, se3_inv, so3_exp
from canopy.loop import LoopParams, describe_stereo_pair, with_bow
from canopy.loop.detector import LoopDetector
from canopy.loop.mono import (MonoLoopCloser, MonoLoopConstraint, apply_sim3_correction, relocalise_mono,
                              verify_candidate_mono)
from canopy.loop.pose_graph import LOOP, PoseGraphEdge, essential_graph_edges
from canopy.loop.sim3 import (estimate_sim3_ransac, from_gtsam, optimise_sim3_pose_graph, rigid_pose, sim3_inv,
                              sim3_matrix, sim3_parts, to_gtsam)
from canopy.metrics import ate_sim3
from canopy.mono import MonoParams
from shared.types import StereoCalibration

K = np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]])


def _project(P):
    return P[:, :2] / P[:, 2:] * 400.0 + [320.0, 240.0]


def test_sim3_algebra_round_trips_through_gtsam():
    S = sim3_matrix(so3_exp([0.2, -0.4, 0.1]), [1.0, -2.0, 0.5], 1.7)
    R, t, s = sim3_parts(S)
    assert s == pytest.approx(1.7) and np.allclose(R @ R.T, np.eye(3))
    assert np.allclose(sim3_inv(S) @ S, np.eye(4))
    assert np.allclose(from_gtsam(to_gtsam(S)), S)
    x = np.array([0.3, 0.2, -1.0])
    assert np.allclose(to_gtsam(S).transformFrom(x), S[:3, :3] @ x + S[:3, 3])   # same action on points
    assert np.allclose(rigid_pose(S)[:3, :3], R) and np.allclose(rigid_pose(S)[:3, 3], t)


def test_sim3_ransac_recovers_scale_and_pose_despite_outliers():
    rng = np.random.default_rng(0)
    P_b = np.column_stack([rng.uniform(-2, 2, 120), rng.uniform(-1.5, 1.5, 120), rng.uniform(3, 8, 120)])
    S_ba = sim3_matrix(so3_exp([0.05, -0.1, 0.02]), [0.3, -0.1, 0.2], 1.3)
    P_a = (P_b - S_ba[:3, 3]) @ np.linalg.inv(S_ba[:3, :3]).T
    uv_a, uv_b = _project(P_a), _project(P_b)
    P_b_obs = P_b.copy()
    P_b_obs[:30] += rng.normal(0, 1.0, (30, 3))      # a quarter of the pairs are wrong points
    est = estimate_sim3_ransac(P_a, P_b_obs, uv_a, uv_b, K, 9.21, iterations=200, min_inliers=20, seed=1)
    assert est.S is not None
    assert np.abs(est.S - S_ba).max() < 1e-9
    assert est.inliers[30:].all() and est.inliers[:30].sum() <= 2
    # a set with no consistent similarity is refused, with the reason
    bad = estimate_sim3_ransac(P_a, rng.permutation(P_b), uv_a, rng.permutation(uv_b), K, 9.21, 100, 20)
    assert bad.S is None and "inliers" in bad.reason


def _circle(n=40, radius=5.0):
    poses = []
    for k in range(n):
        a = 2 * np.pi * k / n
        T = np.eye(4)
        T[:3, :3] = so3_exp([0, -a, 0])
        T[:3, 3] = [radius * np.sin(a), 0, radius * np.cos(a) - radius]
        poses.append(T)
    return poses


def test_sim3_pose_graph_removes_scale_drift_around_a_loop():
    """Odometry whose scale grows 1 % per keyframe; one loop edge (query = last keyframe sees
    the first) with the exact relative pose and scale: the Sim(3) graph brings the path back
    onto the truth (up to one similarity), which an SE(3) correction cannot do for scale."""
    truth = _circle()
    n = len(truth)
    drifted = [truth[0]]
    for k in range(1, n):
        rel = se3_inv(truth[k - 1]) @ truth[k]
        rel[:3, 3] *= 1.01 ** k
        drifted.append(drifted[-1] @ rel)
    poses = dict(enumerate(drifted))
    # the loop measures the last camera in the first camera's frame, in the first one's units
    rel = se3_inv(truth[0]) @ truth[n - 1]
    s_loop = 1.0 / 1.01 ** (n - 1)
    edges = essential_graph_edges(list(range(n)), poses, {},
                                  [PoseGraphEdge(0, n - 1, sim3_matrix(rel[:3, :3], rel[:3, 3], s_loop), LOOP)], 100)
    sig = (0.01, 0.01, 0.01)
    res = optimise_sim3_pose_graph(poses, edges, {"odometry": sig, "covisibility": sig, "loop": sig}, 2.0, 50, fixed=0)
    after = np.array([rigid_pose(res.poses[k]) for k in range(n)])
    before_err = ate_sim3(np.array(drifted), np.array(truth))["rmse"]
    after_err = ate_sim3(after, np.array(truth))["rmse"]
    assert before_err > 0.3 and after_err < 0.02
    assert np.linalg.norm(after[-1][:3, 3] - truth[-1][:3, 3]) < 0.01
    assert res.final_error < 0.1 * res.initial_error
    # the monocular loop closer's own step (its default sigmas): rigid poses out, similarity corrections
    closer = MonoLoopCloser(StereoCalibration(400.0, 400.0, 320.0, 240.0, 0.1, 640, 480))
    poses_after, corrections, (e0, e1) = closer.optimise(poses, edges, fixed=0)
    assert ate_sim3(np.array([poses_after[k] for k in range(n)]), np.array(truth))["rmse"] < 0.05 and e1 < 0.1 * e0
    assert all(np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3)) for T in poses_after.values())
    # the query's map is shrunk back to the candidate's units: its correction carries the loop scale
    assert sim3_parts(corrections[n - 1])[2] == pytest.approx(s_loop, rel=0.02)
    assert sim3_parts(corrections[0])[2] == pytest.approx(1.0, abs=1e-6)


def test_sim3_correction_moves_and_scales_landmarks_with_their_keyframe():
    kf = {0: SimpleNamespace(T_world_cam=np.eye(4)), 5: SimpleNamespace(T_world_cam=np.eye(4))}
    kf[5].T_world_cam[:3, 3] = [1.0, 0, 0]
    lms = {1: SimpleNamespace(position=np.array([0.0, 0, 2]), obs={0: 0}),
           2: SimpleNamespace(position=np.array([1.0, 0, 2]), obs={5: 3, 7: 1})}
    mapper = SimpleNamespace(keyframes=kf, landmarks=lms)
    C = sim3_matrix(so3_exp([0, 0.1, 0]), [0.5, 0, 0], 2.0)
    assert apply_sim3_correction(mapper, {5: C}) == 2
    assert np.allclose(kf[0].T_world_cam, np.eye(4))             # older than the correction: stays
    assert np.allclose(lms[1].position, [0, 0, 2])
    assert np.allclose(lms[2].position, C[:3, :3] @ [1.0, 0, 2] + C[:3, 3])   # scaled and moved
    assert np.allclose(kf[5].T_world_cam, rigid_pose(C @ _tx(1.0)))
    assert np.allclose(kf[5].T_world_cam[:3, :3] @ kf[5].T_world_cam[:3, :3].T, np.eye(3))  # still rigid


def _tx(x):
    T = np.eye(4)
    T[0, 3] = x
    return T


# ----------------------------------------------------------------------------- rendered revisit
CAND_UNIT, QUERY_UNIT = 3.0, 2.4     # metres per map unit on each side (the scale has drifted)


@pytest.fixture(scope="module")
def day_loop_mono_views():
    """Rendered views of the generated day-loop (exact poses) as monocular keyframes: the
    depth of each keypoint's "map point" is the stereo depth in that side's map units."""
    from canopy.synthetic import SequenceGenerator, resolve_params

    gen = SequenceGenerator(resolve_params("day-loop"), seed=0)
    P = np.array([T[:3, 3] for T in gen.track.poses])
    half = len(P) // 2
    revisit = half + int(np.argmin(np.linalg.norm(P[half:] - P[5], axis=1)))
    views = {}
    for i, unit in ((5, CAND_UNIT), (revisit, QUERY_UNIT), (300, CAND_UNIT)):
        left, right, _ = gen.stereo(i)
        kf = describe_stereo_pair(i, 0.0, left, right, gen.calibration)
        views[i] = replace(kf, depth=np.where(kf.depth > 0, kf.depth / unit, -1.0), u_right=np.full(len(kf), -1.0))
    return gen, revisit, views


def test_mono_verification_recovers_the_loop_similarity(day_loop_mono_views):
    gen, revisit, views = day_loop_mono_views
    v = verify_candidate_mono(views[revisit], views[5], gen.calibration, LoopParams(), MonoParams())
    assert v.constraint is not None, v.reason
    c = v.constraint
    assert isinstance(c, MonoLoopConstraint)
    # the views' stereo depths (11 cm baseline, points 2-8 m away) carry a few % of noise
    assert c.scale == pytest.approx(QUERY_UNIT / CAND_UNIT, rel=0.05)
    T_true = se3_inv(gen.track.poses[5]) @ gen.track.poses[revisit]      # metres
    R, t, s = sim3_parts(c.S_cand_query)
    assert np.degrees(rotation_angle(R.T @ T_true[:3, :3])) < 0.3
    assert np.linalg.norm(t * CAND_UNIT - T_true[:3, 3]) < 0.02          # candidate units -> metres
    # another row of the same-looking orchard is not the place
    assert verify_candidate_mono(views[revisit], views[300], gen.calibration, LoopParams(),
                                 MonoParams()).constraint is None


def test_mono_relocalisation_by_database_query_and_pnp(day_loop_mono_views):
    from canopy.loop.vocabulary import load_vocabulary

    gen, revisit, views = day_loop_mono_views
    voc = load_vocabulary()
    det = LoopDetector(gen.calibration, LoopParams(), voc)
    poses = {}
    for i in (300, 5):
        kf = with_bow(views[i], voc)
        det.keyframes[i] = kf
        det.database.add(i, kf.bow, stats=kf.stats)
        poses[i] = gen.track.poses[i].copy()
        poses[i][:3, 3] /= CAND_UNIT                                       # the map's units
    lost = with_bow(replace(views[revisit], depth=np.full(len(views[revisit]), -1.0)), voc)
    found = relocalise_mono(lost, det, poses, gen.calibration, LoopParams())
    assert found is not None
    T_wc, kf, n_inl = found
    assert kf == 5 and n_inl >= LoopParams().reloc_min_inliers
    assert np.linalg.norm(T_wc[:3, 3] * CAND_UNIT - gen.track.poses[revisit][:3, 3]) < 0.02
    assert np.degrees(rotation_angle(T_wc[:3, :3].T @ gen.track.poses[revisit][:3, :3])) < 0.3
    # an empty database relocalises nothing
    assert relocalise_mono(lost, LoopDetector(gen.calibration, LoopParams(), voc), {}, gen.calibration,
                           LoopParams()) is None


def test_lost_mono_tracker_relocalises_into_the_same_map_on_kitti():
    """KITTI 06, first 12 frames mapped with the loop closer's database filled; then the
    tracker is lost with no local map left (as after driving far away) and is shown frame 6
    again: the database query + PnP put it back on the same map at the pose it had there."""
    from canopy.config import load_run_config
    from canopy.loop.keyframe import with_bow
    from canopy.loop.mono import MonoLoopCloser, make_mono_relocaliser, place_keyframe_from_mono_map
    from canopy.loop.vocabulary import load_vocabulary
    from canopy.mono import MonoMapper, MonoTracker
    from canopy.sources import open_source

    src = open_source("kitti", max_frames=12)
    voc = load_vocabulary()
    cfg = load_run_config("kitti")
    mono = cfg.mono  # the shipped config: mono.n_features 2000 where stereo runs 1600
    tracker = MonoTracker(src.calibration, cfg.tracking, mono)
    mapper = MonoMapper(src.calibration, mono)
    closer = MonoLoopCloser(src.calibration, LoopParams(), voc, mono)
    tracker.relocaliser = make_mono_relocaliser(closer, mapper, voc)
    poses = {}
    for i in range(len(src)):
        res = tracker.track(src.frame(i))
        poses[i] = res.T_world_cam.copy()
        for kf in res.keyframes:
            update = mapper.insert_keyframe(kf)
            closer.add_keyframe(with_bow(place_keyframe_from_mono_map(kf, mapper), voc), update.keyframe_poses)
            tracker.apply_map_update(update)
    assert res.status == "ok" and len(closer.detector.database) >= 3
    # lost, its local map gone: only the database can tell where frame 6 is
    tracker._view = type(tracker._view)()
    tracker._last_matched = (np.zeros((0, 3)), tracker._last_matched[1][:0], np.zeros(0, np.int64))
    tracker._lost_run = 1
    again = src.frame(6)
    res = tracker.track(type(again)(100, 100.0, again.left, again.right))
    assert res.status == "ok" and tracker.n_relocalised == 1
    step = np.linalg.norm(poses[7][:3, 3] - poses[6][:3, 3])          # one frame of driving, map units
    # (local BA has refined the map since frame 6 was tracked: a small fraction of a step apart)
    assert np.linalg.norm(res.T_world_cam[:3, 3] - poses[6][:3, 3]) < 0.25 * step
    assert np.degrees(rotation_angle(res.T_world_cam[:3, :3].T @ poses[6][:3, :3])) < 0.2
