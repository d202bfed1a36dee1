"""Monocular local mapping on keyframes built from exact geometry (issue 13): epipolar
triangulation recovers the points, local BA (GTSAM projection factors) repairs a perturbed
pose, and the updates carry the map back to tracking."""
from __future__ import annotations

import numpy as np

from canopy.frontend.geometry import rotation_angle, se3_exp, se3_inv, so3_exp
from canopy.mono import MonoParams
from canopy.mono.mapper import MAPPER_ID_BASE, MonoMapper
from protocol.messages import KeyframeData
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)


def _pose(angles_deg, position):
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.radians(angles_deg))
    T[:3, 3] = position
    return T


def _scene(seed=0, n=700):
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-5, 5, n), rng.uniform(-3, 3, n), rng.uniform(4, 12, n)])
    desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)       # one distinct descriptor per point
    poses = [_pose([0, 0, 0], [0, 0, 0]), _pose([0.5, -2, 0], [0.4, 0.0, 0.1]),
             _pose([1.0, -4, 0.5], [0.8, 0.05, 0.2])]
    return X, desc, poses


def _keyframe(index, T_wc, X, desc, landmark_of_point, depth_ids=None):
    """Keypoints = exact projections of the visible points; ``landmark_of_point`` maps a point
    to an existing landmark id (-1: unmatched); ``depth_ids``: the initial map's reserved ids."""
    T_cw = se3_inv(T_wc)
    Pc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
    uv = Pc[:, :2] / Pc[:, 2:3] * [CALIB.fx, CALIB.fy] + [CALIB.cx, CALIB.cy]
    vis = np.flatnonzero((Pc[:, 2] > 0) & (uv >= 0).all(1) & (uv < [CALIB.width, CALIB.height]).all(1))
    n = len(vis)
    depth = np.full(n, -1.0, np.float32)
    new_ids = np.full(n, -1, np.int64)
    if depth_ids is not None:
        has = depth_ids[vis] >= 0
        depth[has] = Pc[vis[has], 2]
        new_ids[has] = depth_ids[vis[has]]
    kf = KeyframeData(index=index, timestamp=0.1 * index, T_world_cam=T_wc, uv=uv[vis].astype(np.float32),
                      u_right=np.full(n, -1, np.float32), depth=depth, descriptors=desc[vis],
                      octave=np.zeros(n, np.int32), landmark_ids=landmark_of_point[vis].copy(),
                      new_landmark_ids=new_ids, restart=index == 0)
    return kf, vis


def _initial_map(mapper, X, desc, poses, n_init=250):
    init_ids = np.full(len(X), -1, np.int64)
    init_ids[:n_init] = np.arange(n_init)
    kf0, _ = _keyframe(0, poses[0], X, desc, np.full(len(X), -1, np.int64), depth_ids=init_ids)
    mapper.insert_keyframe(kf0)
    kf1, _ = _keyframe(1, poses[1], X, desc, init_ids)
    return mapper.insert_keyframe(kf1), init_ids


def test_triangulation_between_keyframes_recovers_the_points():
    X, desc, poses = _scene()
    mapper = MonoMapper(CALIB, MonoParams())
    update, init_ids = _initial_map(mapper, X, desc, poses)
    assert len(update) >= 200                       # the initial map comes back to tracking
    # KF1 already triangulated the points it shares with KF0 beyond the initial map
    new = [lm for lm in mapper.landmarks.values() if lm.id >= MAPPER_ID_BASE]
    assert len(new) > 200
    kf2, vis2 = _keyframe(2, poses[2], X, desc, init_ids)
    mapper.insert_keyframe(kf2)
    errors = []
    for lm in mapper.landmarks.values():
        # which true point is this? every observation must be of the same one
        truths = set()
        for k, i in lm.obs.items():
            uv = mapper.keyframes[k].uv[i]
            T_cw = se3_inv(poses[k])
            Pc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
            proj = Pc[:, :2] / Pc[:, 2:3] * [CALIB.fx, CALIB.fy] + [CALIB.cx, CALIB.cy]
            truths.add(int(np.argmin(((proj - uv) ** 2).sum(1))))
        assert len(truths) == 1, "a landmark joins observations of different points"
        errors.append(np.linalg.norm(lm.position - X[truths.pop()]))
    assert np.max(errors) < 1e-3
    assert mapper.n_triangulated > 300


def test_local_ba_repairs_a_perturbed_keyframe_pose():
    X, desc, poses = _scene(seed=1)
    mapper = MonoMapper(CALIB, MonoParams())
    _, init_ids = _initial_map(mapper, X, desc, poses)
    ids_now = np.full(len(X), -1, np.int64)
    for lm in mapper.landmarks.values():     # KF2 sees every landmark made so far (as tracking would find them)
        k, i = next(iter(lm.obs.items()))
        ids_now[_truth_index(mapper, X, poses, k, i)] = lm.id
    wrong = se3_exp([0.004, -0.006, 0.003, 0.03, -0.02, 0.02]) @ poses[2]   # ~0.45 deg, ~4 cm off
    kf2, _ = _keyframe(2, poses[2], X, desc, ids_now)
    kf2.T_world_cam = wrong
    update = mapper.insert_keyframe(kf2)
    T = update.keyframe_poses[2]
    assert np.linalg.norm(T[:3, 3] - poses[2][:3, 3]) < 2e-3
    assert np.degrees(rotation_angle(T[:3, :3].T @ poses[2][:3, :3])) < 0.02
    assert 0 not in update.keyframe_poses            # the segment's first keyframe holds the gauge


def _truth_index(mapper, X, poses, k, i):
    T_cw = se3_inv(poses[k])
    Pc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
    proj = Pc[:, :2] / Pc[:, 2:3] * [CALIB.fx, CALIB.fy] + [CALIB.cx, CALIB.cy]
    return int(np.argmin(((proj - mapper.keyframes[k].uv[i]) ** 2).sum(1)))


def test_points_seen_by_two_keyframes_only_are_culled_later():
    X, desc, poses = _scene(seed=2)
    params = MonoParams()
    mapper = MonoMapper(CALIB, params)
    _, init_ids = _initial_map(mapper, X, desc, poses)
    made = {lid for lid in mapper.landmarks if lid >= MAPPER_ID_BASE}
    assert made
    # later keyframes that re-observe only the initial map: the recent points are never found again
    for k in range(2, 2 + params.cull_age_keyframes + 1):
        T = poses[2].copy()
        T[:3, 3] += [0.05 * k, 0, 0]
        kf, _ = _keyframe(k, T, X[:0].reshape(0, 3), desc[:0], np.zeros(0, np.int64))
        kf.seen_ids = np.array(sorted(made), np.int64)
        kf.seen_visible = np.full(len(made), 3, np.int32)
        kf.seen_found = np.zeros(len(made), np.int32)
        mapper.insert_keyframe(kf)
    assert not (made & set(mapper.landmarks))
    # the initial two-view map is not "recent" (ORB-SLAM): it stays
    n_init_two_views = len(set(range(250)) & {lid for lid, lm in mapper.landmarks.items() if len(lm.obs) >= 2})
    assert n_init_two_views >= 200 and sum(lid < 250 for lid in mapper.landmarks) == n_init_two_views


def test_fusion_gives_a_missed_point_its_new_view_and_merges_duplicates():
    X, desc, poses = _scene(seed=3)
    mapper = MonoMapper(CALIB, MonoParams())
    _, init_ids = _initial_map(mapper, X, desc, poses)
    # KF2 as tracking would hand it over, but tracking missed point 0 and point 1 was made
    # twice (a duplicate landmark seen by KF1 only, sharing KF1's keypoint with the original)
    ids = init_ids.copy()
    ids[0] = -1
    kf2, vis2 = _keyframe(2, poses[2], X, desc, ids)
    i0 = int(np.flatnonzero(vis2 == 0)[0])
    assert kf2.landmark_ids[i0] == -1
    original = mapper.landmarks[1]
    dup_id = 10**6
    from canopy.mono.mapper import MonoLandmark
    mapper.landmarks[dup_id] = MonoLandmark(dup_id, original.position + 1e-4, original.descriptor.copy(),
                                            {}, segment=original.segment, recent=False)
    kf2.landmark_ids[np.flatnonzero(vis2 == 1)[0]] = dup_id
    mapper.insert_keyframe(kf2)
    assert 0 in mapper.landmarks and 2 in mapper.landmarks[0].obs          # the missed view was found
    assert mapper.keyframes[2].landmark[i0] == 0
    assert mapper.n_fused >= 1 and (dup_id in mapper.landmarks) != (1 in mapper.landmarks)
    survivor = mapper.landmarks.get(1) or mapper.landmarks[dup_id]
    assert {0, 1, 2} <= set(survivor.obs)                                  # one landmark, all three views
