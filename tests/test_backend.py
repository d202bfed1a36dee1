"""Local mapping: GTSAM local BA on generated scenes with exact ground truth, culling."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend import LocalMapper, MappingParams
from canopy.frontend import KeyframeData, LocalMapUpdate
from canopy.frontend.geometry import project_stereo, rotation_angle, se3_exp, se3_inv
from shared.errors import ConfigError
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)
N_KF = 5


def scene(rng, n=250):
    """Points in front of a camera path moving forward/sideways; true T_world_cam per keyframe."""
    poses = [se3_exp(np.array([0.0, 0.02 * k, 0.0, 0.15 * k, 0.0, 0.25 * k])) for k in range(N_KF)]
    X = np.stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(4, 9, n)], axis=1)
    return poses, X


def keyframe(k, T_true, T_init, X, ids_existing, ids_new, rng, depth_noise=0.0, pixel_offsets=None):
    meas, Pc = project_stereo(se3_inv(T_true), X, CALIB)
    if pixel_offsets is not None:
        meas = meas + pixel_offsets
    n = len(X)
    depth = Pc[:, 2] * (1.0 + depth_noise * rng.standard_normal(n))
    return KeyframeData(
        index=k, timestamp=0.1 * k, T_world_cam=T_init, uv=meas[:, :2].astype(np.float32),
        u_right=meas[:, 2].astype(np.float32), depth=depth.astype(np.float32),
        descriptors=rng.integers(0, 256, (n, 32), dtype=np.uint8), octave=np.zeros(n, np.int32),
        landmark_ids=ids_existing, new_landmark_ids=ids_new, restart=(k == 0))


def run_ba(rng, pose_noise=(0.01, 0.03), depth_noise=0.03, outlier=False, solver="schur", mono_fraction=0.0):
    poses, X = scene(rng)
    n = len(X)
    mapper = LocalMapper(CALIB, MappingParams(ba_iterations=20, ba_solver=solver))
    ids = np.arange(n, dtype=np.int64)
    updates = []
    for k in range(N_KF):
        if k == 0:
            T_init = poses[0]  # the first keyframe is the gauge and stays fixed
            kf = keyframe(0, poses[0], T_init, X, np.full(n, -1, np.int64), ids, rng, depth_noise)
        else:
            xi = np.concatenate([pose_noise[0] * rng.standard_normal(3), pose_noise[1] * rng.standard_normal(3)])
            T_init = poses[k] @ se3_exp(xi)
            off = None
            if outlier:  # landmark 0 is observed 25 px away from where it is in every later keyframe
                off = np.zeros((n, 3))
                off[0] = [25.0, -20.0, 25.0]
            kf = keyframe(k, poses[k], T_init, X, ids, np.full(n, -1, np.int64), rng, pixel_offsets=off)
            kf.u_right[rng.random(n) < mono_fraction] = -1.0  # no stereo match: a monocular observation
        updates.append(mapper.insert_keyframe(kf))
    return mapper, poses, X, updates


def test_mapping_params_validate():
    with pytest.raises(ConfigError, match="window_size"):
        MappingParams(window_size=1)


@pytest.mark.parametrize("solver", ["schur", "gtsam"])
def test_local_ba_recovers_true_poses_and_points(solver):
    rng = np.random.default_rng(0)
    mapper, poses, X, updates = run_ba(rng, solver=solver)
    traj = mapper.keyframe_trajectory()
    assert len(traj) == N_KF
    for T_est, T_true in zip(traj.poses, poses):
        err = se3_inv(T_true) @ T_est
        assert np.linalg.norm(err[:3, 3]) < 1e-3
        assert np.degrees(rotation_angle(err[:3, :3])) < 0.01
    pts = np.array([mapper.landmarks[i].position for i in sorted(mapper.landmarks)])
    assert np.median(np.linalg.norm(pts - X[sorted(mapper.landmarks)], axis=1)) < 1e-3
    last = updates[-1]
    assert isinstance(last, LocalMapUpdate) and last.keyframe_index == N_KF - 1
    assert set(last.keyframe_poses) == set(range(1, N_KF))  # the window minus the fixed gauge
    assert len(last) == len(mapper.landmarks) and last.descriptors.shape == (len(last), 32)
    assert {"insert", "ba", "cull", "total"} <= set(last.timings)


@pytest.mark.parametrize("solver", ["schur", "gtsam"])
def test_ba_is_robust_and_culls_outlier_landmark(solver):
    rng = np.random.default_rng(1)
    mapper, poses, X, _ = run_ba(rng, outlier=True, solver=solver)
    assert 0 not in mapper.landmarks          # its bad observations were dropped, then the landmark
    assert len(mapper.landmarks) >= len(X) - 5
    assert mapper.n_culled >= 1
    for T_est, T_true in zip(mapper.keyframe_trajectory().poses, poses):
        assert np.linalg.norm((se3_inv(T_true) @ T_est)[:3, 3]) < 2e-3


def test_schur_solver_matches_gtsam_graph():
    """The numpy Schur-complement BA minimises the same robust cost as the GTSAM graph: with
    noisy poses and depths, stereo and monocular observations, both land on the same optimum."""
    out = {}
    for solver in ("schur", "gtsam"):
        mapper, _, _, _ = run_ba(np.random.default_rng(3), pose_noise=(0.02, 0.05), depth_noise=0.05,
                                 solver=solver, mono_fraction=0.3)
        out[solver] = mapper
    a, b = out["schur"], out["gtsam"]
    for k in a.keyframes:
        assert np.abs(a.keyframes[k].T_world_cam - b.keyframes[k].T_world_cam).max() < 1e-6
    assert a.landmarks.keys() == b.landmarks.keys()
    diff = [np.linalg.norm(a.landmarks[i].position - b.landmarks[i].position) for i in a.landmarks]
    assert max(diff) < 1e-5


def test_mapping_params_reject_unknown_solver():
    with pytest.raises(ConfigError, match="ba_solver"):
        MappingParams(ba_solver="ceres")


def test_restart_starts_new_segment_without_links():
    rng = np.random.default_rng(2)
    poses, X = scene(rng, 60)
    n = len(X)
    mapper = LocalMapper(CALIB)
    mapper.insert_keyframe(keyframe(0, poses[0], poses[0], X, np.full(n, -1, np.int64), np.arange(n), rng))
    kf = keyframe(1, poses[1], poses[1], X, np.full(n, -1, np.int64), np.arange(n) + 1000, rng)
    kf.restart = True
    upd = mapper.insert_keyframe(kf)
    assert set(upd.landmark_ids.tolist()) == set(range(1000, 1000 + n))
    assert mapper.keyframes[1].segment == mapper.keyframes[0].segment + 1


def test_schur_solver_sums_repeated_observations():
    """A pose that observes a point twice contributes both blocks to the Schur complement: with
    every observation given twice (the cost doubles, the optimum stays) the solver lands on the
    same optimum as with each observation once."""
    from canopy.backend.stereo_ba import StereoEdges, bundle_adjust_points

    rng = np.random.default_rng(4)
    poses, X = scene(rng, n=60)
    T_true = np.stack([se3_inv(T) for T in poses])
    edges = []
    for k in range(N_KF):
        meas, _ = project_stereo(T_true[k], X, CALIB)
        edges.append((np.full(len(X), k), np.arange(len(X)), meas))
    pose, point, meas = (np.concatenate(c) for c in zip(*edges))
    n_local = N_KF - 1  # the last pose is the fixed gauge
    order = np.r_[1:N_KF, 0]
    T_init = T_true[order].copy()
    for i in range(n_local):
        T_init[i] = se3_exp(np.r_[0.01 * rng.standard_normal(3), 0.03 * rng.standard_normal(3)]) @ T_init[i]
    X_init = X + 0.05 * rng.standard_normal(X.shape)
    remap = np.argsort(order)[pose]

    def solve(reps):
        e = StereoEdges(np.tile(remap, reps), np.tile(point, reps), np.tile(meas, (reps, 1)),
                        np.ones(reps * len(pose), bool), np.ones(reps * len(pose)), np.full(reps * len(pose), 1e3))
        return bundle_adjust_points(T_init, n_local, X_init, e, CALIB, 30)

    once, twice = solve(1), solve(2)
    assert np.abs(once[0] - T_true[order]).max() < 1e-6
    assert np.abs(twice[0] - once[0]).max() < 1e-8
    assert np.abs(twice[1] - X).max() < 1e-6


def test_local_map_ids_are_the_sorted_distinct_landmarks_of_the_window():
    from canopy.backend.map_store import _sorted_unique_ids

    rng = np.random.default_rng(4)
    dense = rng.integers(-1, 5000, 36000)          # keypoint slots: -1 (no landmark) or an id
    sparse = np.array([-1, 7, 10 ** 12, 7, 3, -1, 10 ** 12], np.int64)   # a loaded map's far-apart ids
    for ids in (dense, sparse, np.full(5, -1), np.zeros(0, np.int64)):
        ref = np.unique(ids[ids >= 0]).astype(np.int64)
        out = _sorted_unique_ids(ids)
        assert out.dtype == np.int64
        np.testing.assert_array_equal(out, ref)


def test_final_projection_is_the_projection_at_the_returned_estimate():
    """``bundle_adjust_points(..., final_projection=...)`` hands back LM's own projection of the
    edges at the estimate it returns, so local BA's outlier test reuses it: its chi2 must equal a
    fresh ``edge_chi2`` there bit for bit, whether LM converged, ran out of iterations after one
    step, or accepted no step at all (started at the optimum)."""
    from canopy.backend.stereo_ba import StereoEdges, bundle_adjust_points, edge_chi2, projection_chi2

    rng = np.random.default_rng(7)
    poses, X = scene(rng, n=80)
    T_true = np.stack([se3_inv(T) for T in poses])
    pose, point, meas = [], [], []
    for k in range(N_KF):
        m, _ = project_stereo(T_true[k], X, CALIB)
        pose.append(np.full(len(X), k))
        point.append(np.arange(len(X)))
        meas.append(m)
    pose, point, meas = np.concatenate(pose), np.concatenate(point), np.concatenate(meas)
    noisy = meas + rng.normal(0, 0.5, meas.shape)
    noisy[::17] += 25.0                                   # a few outliers for the Huber kernel
    stereo = rng.random(len(pose)) < 0.8
    sigma = 1.2 ** rng.integers(0, 4, len(pose))
    n_local = N_KF - 1
    T_init = T_true.copy()
    for i in range(n_local):
        T_init[i] = se3_exp(np.r_[0.01 * rng.standard_normal(3), 0.03 * rng.standard_normal(3)]) @ T_init[i]
    X_init = X + 0.05 * rng.standard_normal(X.shape)
    cases = [(noisy, T_init, X_init, 30), (noisy, T_init, X_init, 1), (meas, T_true, X, 10)]
    iterations, unchanged = [], []
    for m, T0, X0, max_it in cases:
        edges = StereoEdges(pose, point, m, stereo, sigma, np.full(len(pose), 2.8))
        final = []
        T, Xo, it = bundle_adjust_points(T0, n_local, X0, edges, CALIB, max_it, final_projection=final)
        iterations.append(it)
        unchanged.append(np.array_equal(T, T0) and np.array_equal(Xo, X0))
        assert len(final) == 1
        np.testing.assert_array_equal(projection_chi2(*final[0], sigma, 0.05), edge_chi2(T, Xo, edges, CALIB, 0.05))
    assert iterations[0] > 1 and iterations[1] == 1      # converged after several steps; stopped after one
    assert unchanged == [False, False, True]              # at the optimum no step is accepted


def test_point_and_pose_blocks_equal_the_per_edge_products():
    """The normal equations' point blocks (six entries of each symmetric 3x3 from component vectors)
    and pose blocks (one GEMM per pose, in chunks) equal the per-edge matmul definition, with a
    point seen several times, a local pose with no edge and chunks shorter than a pose's edges."""
    import canopy.backend.stereo_ba as sb

    rng = np.random.default_rng(3)
    E, P, L = 400, 120, 4
    point = np.sort(rng.integers(0, P - 1, E))          # sorted by point, as local BA gives them; point P-1 unseen
    pose = rng.integers(0, L - 1, E)                     # pose L-1 has no edge
    Jx, Jc, w, r = rng.normal(size=(E, 3, 3)), rng.normal(size=(E, 3, 6)), rng.uniform(0.1, 2, E), rng.normal(size=(E, 3))
    Wr = r * w[:, None]
    Hpp, bp = sb._point_blocks(Jx, w, Wr, sb._Groups(point, P))
    JxT = Jx.transpose(0, 2, 1)
    ref_H = np.zeros((P, 3, 3))
    ref_b = np.zeros((P, 3))
    np.add.at(ref_H, point, JxT @ (Jx * w[:, None, None]))
    np.add.at(ref_b, point, (JxT @ Wr[..., None])[..., 0])
    assert np.allclose(Hpp, ref_H, rtol=1e-12, atol=1e-12) and np.allclose(bp, ref_b, rtol=1e-12, atol=1e-12)
    assert np.array_equal(Hpp, Hpp.transpose(0, 2, 1)) and not Hpp[P - 1].any()
    old = sb.GRAM_ROWS
    try:
        for rows in (old, 30):   # 30 rows: every pose's edges span several chunks
            sb.GRAM_ROWS = rows
            Hcc, bc = sb._pose_blocks(Jc, w[:, None, None], Wr, sb._Groups(pose, L))
            JcT = Jc.transpose(0, 2, 1)
            ref_H = np.zeros((L, 6, 6))
            ref_b = np.zeros((L, 6))
            np.add.at(ref_H, pose, JcT @ (Jc * w[:, None, None]))
            np.add.at(ref_b, pose, (JcT @ Wr[..., None])[..., 0])
            assert np.allclose(Hcc, ref_H, rtol=1e-12, atol=1e-12) and np.allclose(bc, ref_b, rtol=1e-12, atol=1e-12)
            assert not Hcc[L - 1].any() and not bc[L - 1].any()
    finally:
        sb.GRAM_ROWS = old


def test_landmark_store_keeps_values_in_rows_and_matches_plain_landmarks():
    """``LocalMapper.landmarks`` keeps positions / descriptors in id-indexed rows: a landmark reads
    and writes its row, a read is a copy (a position taken before BA keeps its value), a pickled
    landmark carries its values, and the local map, ``map_points`` and a far-apart id (rows off)
    give what plain per-object landmarks give."""
    import pickle

    from canopy.backend.map_store import Landmark, LandmarkStore, local_map_update

    rng = np.random.default_rng(5)
    mapper, _, _, updates = run_ba(rng)
    store = mapper.landmarks
    assert isinstance(store, LandmarkStore) and store.rows is not None
    plain = {lid: Landmark(lid, lm.position, lm.descriptor, dict(lm.obs)) for lid, lm in store.items()}
    window = sorted(mapper.keyframes)
    a = local_map_update(99, mapper.keyframes, store, window[1:], window[:1])
    b = local_map_update(99, mapper.keyframes, plain, window[1:], window[:1])
    np.testing.assert_array_equal(a.landmark_ids, b.landmark_ids)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.descriptors, b.descriptors)
    np.testing.assert_array_equal(mapper.map_points(), np.array([lm.position for lm in plain.values()]))
    lm = next(iter(store.values()))
    before = lm.position
    lm.position = before + 1.0
    np.testing.assert_array_equal(before + 1.0, store.rows.pos[lm.id])
    assert not np.array_equal(before, lm.position)         # the earlier read did not change
    lm.descriptor = np.full(32, 7, np.uint8)
    copy = pickle.loads(pickle.dumps(lm))
    assert copy._rows is None and np.array_equal(copy.position, lm.position) and (copy.descriptor == 7).all()
    # an id far beyond the counter's range turns the rows off; every landmark keeps its values
    far = 10 ** 12
    store[far] = Landmark(far, np.ones(3), np.zeros(32, np.uint8), {})
    assert store.rows is None
    np.testing.assert_array_equal(lm.position, before + 1.0)
    assert (lm.descriptor == 7).all() and np.array_equal(store[far].position, np.ones(3))
    np.testing.assert_array_equal(mapper.map_points()[:-1], [x.position for x in list(store.values())[:-1]])


def test_ba_relative_tol_stops_lm_earlier():
    from canopy.backend.stereo_ba import StereoEdges, bundle_adjust_points

    with pytest.raises(ConfigError, match="ba_relative_tol"):
        MappingParams(ba_relative_tol=0.0)
    rng = np.random.default_rng(6)
    poses, X = scene(rng, n=80)
    T_true = np.stack([se3_inv(T) for T in poses])
    meas = [project_stereo(T_true[k], X, CALIB)[0] for k in range(N_KF)]
    e = StereoEdges(np.repeat(np.arange(N_KF), len(X)), np.tile(np.arange(len(X)), N_KF), np.concatenate(meas),
                    np.ones(N_KF * len(X), bool), np.ones(N_KF * len(X)), np.full(N_KF * len(X), 1e3))
    T_init = T_true.copy()
    for i in range(N_KF - 1):
        T_init[i] = se3_exp(np.r_[0.01 * rng.standard_normal(3), 0.03 * rng.standard_normal(3)]) @ T_init[i]
    X_init = X + 0.05 * rng.standard_normal(X.shape)
    fine = bundle_adjust_points(T_init, N_KF - 1, X_init, e, CALIB, 30)
    coarse = bundle_adjust_points(T_init, N_KF - 1, X_init, e, CALIB, 30, relative_tol=0.5)
    assert coarse[2] < fine[2]
    assert np.abs(fine[1] - X).max() < 1e-6
