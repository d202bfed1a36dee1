"""Full bundle adjustment after a loop and landmark fusion across it (AGRI §3.4.2), on a
generated lap with exact ground truth: from a map drifted along the lap, the BA with the
duplicated landmarks at its two ends fused recovers the exact lap, and fusion finds exactly
those duplicates."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.frontend.geometry import rotation_angle, se3_exp, se3_inv
from canopy.loop.full_ba import fuse_across_loop, global_bundle_adjust
from canopy.loop.keyframe import PlaceKeyframe
from canopy.loop.params import LoopParams
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)
N_KF = 24
FIRST_LATE = 19        # keyframes from here on see the start again through duplicated landmarks


def _look_outward(theta: float, radius: float) -> np.ndarray:
    """T_world_cam of a camera on a circle, looking radially out (z forward, y down)."""
    c, s = np.cos(theta), np.sin(theta)
    z = np.array([c, s, 0.0])
    y = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = radius * z
    return T


@pytest.fixture(scope="module")
def lap():
    rng = np.random.default_rng(5)
    gt = {k: _look_outward(2 * np.pi * k / N_KF, 4.0) for k in range(N_KF)}
    n_pts = 900
    ang = rng.uniform(0, 2 * np.pi, n_pts)
    rad = rng.uniform(7.0, 10.0, n_pts)
    X = np.stack([rad * np.cos(ang), rad * np.sin(ang), rng.uniform(-1.5, 1.5, n_pts)], axis=1)
    desc = rng.integers(0, 256, (n_pts, 32), dtype=np.uint8)
    # the map as odometry left it: a drift growing along the lap (k * eps, world frame)
    eps = np.array([0.0, 0.0, 0.004, 0.01, -0.008, 0.004])
    drift = {k: se3_exp(k * eps) for k in range(N_KF)}
    drifted = {k: drift[k] @ gt[k] for k in range(N_KF)}
    seen = {}
    for k in range(N_KF):
        T_cw = se3_inv(gt[k])
        Pc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = CALIB.fx * Pc[:, 0] / Pc[:, 2] + CALIB.cx
            v = CALIB.fy * Pc[:, 1] / Pc[:, 2] + CALIB.cy
        vis = (Pc[:, 2] > 0.5) & (u > 5) & (u < CALIB.width - 5) & (v > 5) & (v < CALIB.height - 5)
        seen[k] = (np.flatnonzero(vis), u, v, Pc[:, 2])
    # landmark ids: physical point j is landmark j, except that late keyframes observe a duplicate
    # (id 10000 + j) of a point the early part of the lap mapped first
    first_seen = {}
    for k in range(N_KF):
        for j in seen[k][0].tolist():
            first_seen.setdefault(j, k)
    duplicated = {j for j, f in first_seen.items() if f < FIRST_LATE and any(j in seen[k][0] for k in range(FIRST_LATE, N_KF))
                  and not any(j in seen[k][0] for k in range(FIRST_LATE - 4, FIRST_LATE))}
    keyframes, positions = {}, {}
    for k in range(N_KF):
        vis, u, v, z = seen[k]
        noise = rng.normal(0, 0.3, (len(vis), 3))
        uv = np.stack([u[vis], v[vis]], axis=1) + noise[:, :2]
        ur = u[vis] - CALIB.fx * CALIB.baseline / z[vis] + noise[:, 2]
        ids = np.array([10000 + j if (j in duplicated and k >= FIRST_LATE) else j for j in vis.tolist()], np.int64)
        d = desc[vis].copy()
        d[:, 0] ^= rng.integers(0, 4, len(vis), dtype=np.uint8)  # a few bits differ between views
        keyframes[k] = PlaceKeyframe(index=k, timestamp=float(k), T_world_cam=drifted[k], uv=uv, u_right=ur,
                                     depth=z[vis], octave=np.zeros(len(vis), np.int64), descriptors=d,
                                     landmark_ids=ids)
        for j, lid in zip(vis.tolist(), ids.tolist()):
            if lid not in positions:  # created by the first keyframe seeing it, in the drifted map
                positions[lid] = drift[k][:3, :3] @ X[j] + drift[k][:3, 3]
    return {"gt": gt, "drifted": drifted, "keyframes": keyframes, "positions": positions,
            "duplicated": duplicated, "X": X}


def _max_errors(poses, gt):
    t = max(np.linalg.norm(poses[k][:3, 3] - gt[k][:3, 3]) for k in gt)
    r = max(np.degrees(rotation_angle(poses[k][:3, :3].T @ gt[k][:3, :3])) for k in gt)
    return t, r


def test_full_ba_with_fused_duplicates_recovers_the_exact_lap(lap):
    params = LoopParams()
    start_t, _ = _max_errors(lap["drifted"], lap["gt"])
    assert start_t > 0.15  # the lap is open: metres of path, centimetres of drift at its end
    alone = global_bundle_adjust(lap["keyframes"], lap["drifted"], lap["positions"], CALIB, params, fixed=0)
    alone_t, _ = _max_errors(alone.poses, lap["gt"])
    alias = {10000 + j: j for j in lap["duplicated"]}
    fused = global_bundle_adjust(lap["keyframes"], lap["drifted"], lap["positions"], CALIB, params, alias=alias, fixed=0)
    fused_t, fused_r = _max_errors(fused.poses, lap["gt"])
    print(f"start {start_t:.3f} m, BA alone {alone_t:.4f} m, BA fused {fused_t:.4f} m {fused_r:.3f} deg")
    assert fused_t < 0.5 * alone_t  # the fused duplicates tie the two ends of the lap
    assert fused_t < 0.03 and fused_r < 0.2   # fused: the exact lap within the noise (0.3 px, 7-10 m depth)
    P = dict(zip(fused.landmark_ids.tolist(), fused.positions))
    err = [np.linalg.norm(P[j] - lap["X"][j]) for j in lap["duplicated"] if j in P]
    assert len(err) > 20 and np.median(err) < 0.02
    assert all(np.allclose(fused.corrections[k] @ lap["drifted"][k], fused.poses[k]) for k in fused.poses)


def test_fusion_finds_the_duplicates_across_the_loop(lap):
    # after the pose-graph correction the two ends are in place (here: the exact poses)
    positions = dict(lap["positions"])
    for j in range(len(lap["X"])):
        for lid in (j, 10000 + j):
            if lid in positions:
                positions[lid] = lap["X"][j]
    alias: dict[int, int] = {}
    fused = fuse_across_loop(lap["keyframes"], lap["gt"], positions, list(range(FIRST_LATE, N_KF)),
                             list(range(0, 5)), CALIB, LoopParams(), alias)
    truth = {10000 + j: j for j in lap["duplicated"]}
    assert fused and all(truth.get(d) == k for d, k in fused.items())   # never a wrong pair
    assert len(fused) >= 0.8 * len(truth)
    assert alias == fused


def test_loop_closer_worker_runs_the_full_ba_in_a_child_process(lap):
    from canopy.loop.closer import LoopCloser
    from canopy.loop.pose_graph import correction_for
    from canopy.loop.worker import LoopWorker

    closer = LoopCloser(CALIB, LoopParams(), None)
    closer.detector.keyframes.update(lap["keyframes"])
    closer.poses = {k: T.copy() for k, T in lap["drifted"].items()}
    closer.positions = dict(lap["positions"])
    closer.alias = {10000 + j: j for j in lap["duplicated"]}
    closer.ba_pending = True
    worker = LoopWorker(closer, None, niceness=0, process=False)
    worker._finish_ba()           # starts the child process and waits for its answer (no thread here)
    assert worker._ba is None and not closer.ba_pending and closer.epoch == 1
    out = []
    while not worker.outbox.empty():
        out.append(worker.outbox.get_nowait())
    answers = [item[2] for item in out if item[0] == "send" and item[2].global_ba]
    extra = {k: v for item in out if item[0] == "extra" for k, v in item[1].items()}
    assert len(answers) == 1 and "global_ba_error" not in extra
    assert 0.25 < extra["global_ba_pixel_sigma"] < 0.35      # the lap's 0.3 px, estimated in the child
    corrections = dict(zip(answers[0].keyframe_ids.tolist(), answers[0].corrections))
    moved = {k: correction_for(k, corrections) @ T for k, T in lap["drifted"].items()}
    t, r = _max_errors(moved, lap["gt"])
    assert t < 0.03 and r < 0.2     # local mapping's drifted map, corrected, is the exact lap
    assert all(np.allclose(closer.poses[k], moved[k]) for k in moved)


def test_fused_landmark_is_merged_in_the_map_and_tracking_sees_the_kept_one():
    from canopy.backend import LocalMapper
    from canopy.backend.map_store import Keyframe, Landmark
    from canopy.loop.correction import fuse_landmarks, refresh_update
    from protocol.messages import LocalMapUpdate

    m = LocalMapper(CALIB)
    d = np.arange(3 * 32, dtype=np.uint8).reshape(3, 32)
    for k, lms in ((0, [1, 2, -1]), (5, [3, 2, 4])):
        m.keyframes[k] = Keyframe(k, float(k), np.eye(4), np.zeros((3, 2)), np.full(3, -1.0), np.zeros(3, np.int64), d,
                                  np.array(lms, np.int64), 0, k)
    for lid, obs in ((1, {0: 0}), (2, {0: 1, 5: 1}), (3, {5: 0}), (4, {5: 2})):
        m.landmarks[lid] = Landmark(lid, np.full(3, float(lid)), d[0], dict(obs))
    assert fuse_landmarks(m, {3: 1, 4: 99}) == 1            # 99 does not exist: 4 is left alone
    assert 3 not in m.landmarks and m.landmarks[1].obs == {0: 0, 5: 0}
    assert m.keyframes[5].landmark.tolist() == [1, 2, 4]
    update = LocalMapUpdate(5, np.array([2, 3, 4], np.int64), np.zeros((3, 3)), np.zeros((3, 32), np.uint8))
    refresh_update(m, update, {3: 1})
    assert update.landmark_ids.tolist() == [1, 2, 4]        # the duplicate's place taken by the kept landmark
    assert np.allclose(update.positions, [[1, 1, 1], [2, 2, 2], [4, 4, 4]])
    assert len(update.descriptors) == 3 and set(update.keyframe_poses) == {0, 5}


def _closer_with_lap(lap, **params):
    from dataclasses import replace as dc_replace

    from canopy.loop.closer import LoopCloser

    closer = LoopCloser(CALIB, dc_replace(LoopParams(), full_ba=False, **params), None)
    for k in range(N_KF):  # as a loaded map: stored, never queried
        kf = lap["keyframes"][k]
        P = np.array([lap["positions"][int(l)] for l in kf.landmark_ids.tolist()], float)
        closer.add_known_keyframe(PlaceKeyframe(index=k, timestamp=float(k), T_world_cam=lap["drifted"][k].copy(),
                                                uv=kf.uv, u_right=kf.u_right, depth=kf.depth, octave=kf.octave,
                                                descriptors=kf.descriptors, landmark_ids=kf.landmark_ids,
                                                landmark_positions=P))
    return closer


def test_fusion_before_the_pose_graph_links_the_two_ends_of_the_loop(lap):
    """ORB-SLAM CorrectLoop order: the query side moved by the verified loop pose finds the
    duplicates (the drifted query side is ~0.3 m off: 4 px windows would miss them), and the
    keyframe pairs they link become loop edges of the pose graph."""
    from canopy.loop.verify import LoopConstraint

    query, cand = N_KF - 1, 0
    constraint = LoopConstraint(query=query, candidate=cand, T_cand_query=se3_inv(lap["gt"][cand]) @ lap["gt"][query],
                                n_matches=100, n_inliers=100, information=np.eye(6),
                                query_keypoints=np.zeros(0, np.int64), candidate_keypoints=np.zeros(0, np.int64))
    truth = {10000 + j: j for j in lap["duplicated"]}
    errors = {}
    for first in (True, False):
        closer = _closer_with_lap(lap, fuse_before_pose_graph=first)
        assert not closer.detector.covisibility.neighbours(query, 1).get(cand)  # the two ends share no landmark yet
        closure = closer.close_loop(constraint)
        assert closure.fused and all(truth.get(d) == k for d, k in closure.fused.items())  # never a wrong pair
        assert all(d not in closer.positions for d in closure.fused)
        errors[first] = _max_errors(closer.poses, lap["gt"])[0], _fused_reprojection_px(closer, closure.fused)
        if first:
            assert closure.timings_ms["loop_connections"] >= 3     # query-side x candidate-side keyframe pairs
            assert len(closure.fused) >= 0.5 * len(truth)
    print(f"pose graph max error / median reprojection of the kept landmarks in the query side: fused first "
          f"{errors[True][0]:.4f} m {errors[True][1]:.2f} px, fused after {errors[False][0]:.4f} m {errors[False][1]:.2f} px")
    # what tracking meets when the correction reaches it (before the full BA): the merged trees
    # where the corrected keyframes at the loop's end see them
    assert errors[True][1] < 0.5 * errors[False][1]
    assert errors[True][0] < 0.3                                # the graph still spreads the drift


def _fused_reprojection_px(closer, fused: dict[int, int]) -> float:
    """Median reprojection error (px) of each kept landmark in the keyframes that observed its
    duplicate, with the closer's corrected poses."""
    err = []
    for k, kf in closer.detector.keyframes.items():
        T_cw = se3_inv(closer.poses[k])
        for i, lid in enumerate(kf.landmark_ids.tolist()):
            keep = fused.get(int(lid))
            if keep is None or keep not in closer.positions:
                continue
            Pc = T_cw[:3, :3] @ closer.positions[keep] + T_cw[:3, 3]
            uv = np.array([CALIB.fx * Pc[0] / Pc[2] + CALIB.cx, CALIB.fy * Pc[1] / Pc[2] + CALIB.cy])
            err.append(np.linalg.norm(uv - kf.uv[i]))
    return float(np.median(err))


def test_a_run_extending_a_loaded_map_continues_its_path_where_it_was_found(lap):
    """The first keyframe after a loaded map counts the distance travelled from the loaded
    keyframe nearest to it, not from the loaded map's end (re-travelling the map's last metres
    must not add up to ``min_loop_path_m`` and let a view further down the row pass as a loop)."""
    closer = _closer_with_lap(lap)
    det = closer.detector
    kf = lap["keyframes"][5]
    new = PlaceKeyframe(index=100, timestamp=100.0, T_world_cam=lap["drifted"][5].copy(), uv=kf.uv, u_right=kf.u_right,
                        depth=kf.depth, octave=kf.octave, descriptors=kf.descriptors, landmark_ids=kf.landmark_ids)
    det.add_keyframe(new)
    assert det._path[100] == det._path[5] < det._path[N_KF - 1]


def test_pixel_noise_estimate_is_the_gaussian_sigma_despite_outliers_and_pyramid_levels():
    from canopy.loop.full_ba import estimate_pixel_noise

    rng = np.random.default_rng(3)
    n = 4000
    octave = rng.integers(0, 4, n)
    res = rng.normal(0.0, 0.4, (n, 3)) * (1.2 ** octave)[:, None]   # 0.4 px at level 0, scaled per level
    res[: n // 2, 2] = np.nan                                          # monocular edges: no right residual
    res[rng.choice(n, n // 20, replace=False)] += rng.choice([-1, 1], (n // 20, 3)) * 3.0  # 5 % gross outliers
    est = estimate_pixel_noise(res, octave, 1.2, np.ones(n, bool))
    assert abs(est - 0.4) < 0.04
    assert np.isnan(estimate_pixel_noise(res, octave, 1.2, np.zeros(n, bool)))


def _rms_error(poses, gt):
    return float(np.sqrt(np.mean([np.sum((poses[k][:3, 3] - gt[k][:3, 3]) ** 2) for k in gt])))


@pytest.mark.parametrize("corrupt", [0.0, 0.03])
def test_full_ba_estimates_the_lap_noise_and_is_closer_to_the_exact_lap(lap, corrupt):
    """The lap's keypoints carry 0.3 px of noise (and, second case, 3 % of the observations are off by
    1.5 px per axis: inside the 1 px chi2 bound, 4.5 < 7.8, but 7 sigma off the real noise). The first
    pass's residuals give 0.3 px back (the fitted landmarks absorb part of the noise: without the
    degrees-of-freedom correction the estimate is 0.24 px and the test drops good edges), and the
    outlier test and second pass at that noise give a lap closer to the exact one than at 1 px."""
    from dataclasses import replace as dc_replace

    rng = np.random.default_rng(11)
    kfs = {}
    for k, kf in lap["keyframes"].items():
        uv = kf.uv.copy()
        bad = rng.random(len(uv)) < corrupt
        uv[bad] += rng.choice([-1.5, 1.5], (int(bad.sum()), 2))
        kfs[k] = PlaceKeyframe(index=k, timestamp=kf.timestamp, T_world_cam=kf.T_world_cam, uv=uv, u_right=kf.u_right,
                               depth=kf.depth, octave=kf.octave, descriptors=kf.descriptors, landmark_ids=kf.landmark_ids)
    alias = {10000 + j: j for j in lap["duplicated"]}
    fixed = global_bundle_adjust(kfs, lap["drifted"], lap["positions"], CALIB,
                                 dc_replace(LoopParams(), full_ba_estimate_noise=False), alias=dict(alias), fixed=0)
    est = global_bundle_adjust(kfs, lap["drifted"], lap["positions"], CALIB, LoopParams(), alias=dict(alias), fixed=0)
    e_fixed, e_est = _rms_error(fixed.poses, lap["gt"]), _rms_error(est.poses, lap["gt"])
    print(f"1 px: {fixed.n_outliers} outliers, rms {e_fixed:.4f} m; estimated {est.pixel_sigma:.3f} px: "
          f"{est.n_outliers} outliers, rms {e_est:.4f} m")
    assert fixed.pixel_sigma == 1.0 and abs(est.pixel_sigma - 0.3) < (0.02 if corrupt == 0 else 0.04)
    assert est.n_outliers > fixed.n_outliers
    assert e_est < 0.9 * e_fixed


@pytest.mark.parametrize("tree", [True, False])
def test_a_keyframe_added_during_the_full_ba_moves_with_its_spanning_tree_parent(lap, tree):
    """A keyframe inserted after the BA's snapshot (here: back at keyframe 12's place, seeing its
    landmarks) is moved with its parent's correction (ORB-SLAM RunGlobalBundleAdjustment), not with
    that of the newest keyframe the BA adjusted (23, half a lap away: a different correction)."""
    from canopy.loop.full_ba import run_ba_job
    from canopy.loop.pose_graph import correction_for

    closer = _closer_with_lap(lap, full_ba_tree_corrections=tree)
    closer.alias.update({10000 + j: j for j in lap["duplicated"]})
    job = closer.ba_job()                       # the snapshot: keyframes 0..23
    kf = lap["keyframes"][12]
    closer.add_known_keyframe(PlaceKeyframe(index=100, timestamp=100.0, T_world_cam=lap["drifted"][12].copy(),
                                            uv=kf.uv, u_right=kf.u_right, depth=kf.depth, octave=kf.octave,
                                            descriptors=kf.descriptors, landmark_ids=kf.landmark_ids))
    assert closer.parent[100] == 12
    result = closer.accept_ba(run_ba_job(job))
    assert 100 not in job["poses"]
    moved = correction_for(100, result.corrections) @ lap["drifted"][12]   # as local mapping applies it
    err = np.linalg.norm(closer.poses[100][:3, 3] - lap["gt"][12][:3, 3])
    print(f"tree={tree}: keyframe 100 {err:.4f} m from its true place")
    assert np.allclose(moved, closer.poses[100])
    if tree:
        assert np.allclose(result.corrections[100], result.corrections[12])
        assert err < 0.03
    else:
        assert err > 0.1


def _with_sliding_silhouettes(lap, share: float, slide_m: float, seed: int = 3):
    """The lap's keyframes with ``share`` of the physical points turned into silhouette points, as
    tracking.contour_landmarks leaves them: measured bearing-only (u_right -1) in every keyframe, and
    no fixed 3D point: a T-junction on a rim is where the rim occludes the background, so each
    keyframe sees it displaced (here by a keyframe-dependent offset of ``slide_m``)."""
    from dataclasses import replace as dc_replace

    rng = np.random.default_rng(seed)
    X, sil = lap["X"], rng.random(len(lap["X"])) < share
    kfs = {}
    for k, kf in lap["keyframes"].items():
        phys = kf.landmark_ids % 10000
        m = sil[phys]
        T_cw = se3_inv(lap["gt"][k])
        Pc = (X[phys[m]] + slide_m * np.array([np.cos(0.7 * k), np.sin(0.7 * k), 0.5 * np.cos(1.3 * k)])) @ T_cw[:3, :3].T \
            + T_cw[:3, 3]
        uv, ur = kf.uv.copy(), kf.u_right.copy()
        uv[m] = np.stack([CALIB.fx * Pc[:, 0] / Pc[:, 2] + CALIB.cx, CALIB.fy * Pc[:, 1] / Pc[:, 2] + CALIB.cy], axis=1)
        ur[m] = -1.0
        kfs[k] = dc_replace(kf, uv=uv, u_right=ur)
    return kfs, set(np.flatnonzero(sil).tolist())


def test_full_ba_leaves_out_landmarks_never_measured_in_stereo(lap):
    """Silhouette landmarks (bearing-only in every keyframe, sliding along their rim) pull the full
    BA off the exact lap when they are in it; left out (loop.full_ba_bearing_only_landmarks false),
    the stereo landmarks alone recover it. A map whose landmarks all have a stereo edge gives the same
    BA either way."""
    from dataclasses import replace as dc_replace

    alias = {10000 + j: j for j in lap["duplicated"]}
    kfs, sil = _with_sliding_silhouettes(lap, share=0.4, slide_m=0.3)
    runs = {inc: global_bundle_adjust(kfs, lap["drifted"], lap["positions"], CALIB,
                                      dc_replace(LoopParams(), full_ba_bearing_only_landmarks=inc), alias=dict(alias),
                                      fixed=0) for inc in (True, False)}
    err = {inc: _max_errors(r.poses, lap["gt"]) for inc, r in runs.items()}
    print(f"with silhouettes {err[True][0]:.3f} m {err[True][1]:.2f} deg, without {err[False][0]:.4f} m "
          f"{err[False][1]:.3f} deg")
    kept = {int(l) % 10000 for l in runs[False].landmark_ids.tolist()}
    assert not kept & sil and len(kept) > 300
    assert {int(l) % 10000 for l in runs[True].landmark_ids.tolist()} & sil
    assert err[False][0] < 0.03 and err[False][1] < 0.2
    assert err[True][0] > 5 * err[False][0]
    plain = [global_bundle_adjust(lap["keyframes"], lap["drifted"], lap["positions"], CALIB,
                                  dc_replace(LoopParams(), full_ba_bearing_only_landmarks=inc), alias=dict(alias), fixed=0)
             for inc in (True, False)]
    assert np.array_equal(plain[0].landmark_ids, plain[1].landmark_ids)
    assert all(np.array_equal(plain[0].poses[k], plain[1].poses[k]) for k in plain[0].poses)


@pytest.mark.parametrize("stereo_only", [True, False])
def test_loop_closer_keeps_no_depth_for_bearing_only_keypoints(lap, stereo_only):
    """Keypoints tracking measures bearing-only keep the stereo depth that initialised their landmark
    in the keyframe; the loop closer drops it (loop.verify_stereo_only), so verification neither uses
    a silhouette's depth as a 3D point nor measures u_right -1 as a right-image column. The monocular
    closer's keyframes carry map-point depths without a right column and keep them."""
    from dataclasses import replace as dc_replace

    from canopy.loop.closer import LoopCloser
    from canopy.loop.mono import MonoLoopCloser

    kfs, _ = _with_sliding_silhouettes(lap, share=0.4, slide_m=0.3)
    closer = LoopCloser(CALIB, dc_replace(LoopParams(), verify_stereo_only=stereo_only), None)
    for k in range(3):
        closer.add_keyframe(dc_replace(kfs[k], depth=kfs[k].depth.copy()))
    for k in range(3):
        stored, bearing = closer.detector.keyframes[k], kfs[k].u_right < 0
        assert bearing.any() and (kfs[k].depth[bearing] > 0).all()
        if stereo_only:
            assert (stored.depth[bearing] == -1).all()
        else:
            assert np.array_equal(stored.depth[bearing], kfs[k].depth[bearing])
        assert np.array_equal(stored.depth[~bearing], kfs[k].depth[~bearing])
    assert MonoLoopCloser(CALIB, LoopParams()).params.verify_stereo_only is False


@pytest.mark.parametrize("fuse_bearing_only", [True, False])
def test_fusion_leaves_bearing_only_keypoints_alone_when_asked(lap, fuse_bearing_only):
    """loop.fuse_bearing_only false: a keypoint tracking measured bearing-only (u_right -1, a contour
    landmark's) takes part in the fusion on neither side of the loop, so a silhouette landmark is not
    merged with a stereo one (which would give it a stereo edge and put it back in the full BA); the
    stereo keypoints' duplicates are fused as before. True: every duplicate, as before."""
    from dataclasses import replace as dc_replace

    rng = np.random.default_rng(11)
    sil = set(np.flatnonzero(rng.random(len(lap["X"])) < 0.4).tolist())
    kfs = {}
    for k, kf in lap["keyframes"].items():
        ur = kf.u_right.copy()
        ur[np.isin(kf.landmark_ids % 10000, list(sil))] = -1.0   # bearing-only in every keyframe
        kfs[k] = dc_replace(kf, u_right=ur)
    positions = dict(lap["positions"])
    for j in range(len(lap["X"])):
        for lid in (j, 10000 + j):
            if lid in positions:
                positions[lid] = lap["X"][j]
    fused = fuse_across_loop(kfs, lap["gt"], positions, list(range(FIRST_LATE, N_KF)), list(range(0, 5)), CALIB,
                             dc_replace(LoopParams(), fuse_bearing_only=fuse_bearing_only), {})
    truth = {10000 + j: j for j in lap["duplicated"]}
    assert all(truth.get(d) == k for d, k in fused.items())
    on_silhouettes = {k for k in fused.values() if k in sil}
    stereo_truth = {d for d, k in truth.items() if k not in sil}
    assert len([d for d in fused if d in stereo_truth]) >= 0.8 * len(stereo_truth)
    if fuse_bearing_only:
        assert len(on_silhouettes) >= 0.8 * len(set(truth.values()) & sil) > 10
    else:
        assert not on_silhouettes


def test_full_ba_down_weights_bearing_only_landmarks_by_the_sigma_factor(lap):
    """loop.full_ba_bearing_only_sigma_factor: the sliding silhouette landmarks stay in the full BA
    but their edges count with a wider pixel sigma; they pull the lap off much less than at the
    stereo points' sigma. Factor 1 is the plain BA."""
    from dataclasses import replace as dc_replace

    alias = {10000 + j: j for j in lap["duplicated"]}
    kfs, sil = _with_sliding_silhouettes(lap, share=0.4, slide_m=0.3)
    runs = {f: global_bundle_adjust(kfs, lap["drifted"], lap["positions"], CALIB,
                                    dc_replace(LoopParams(), full_ba_bearing_only_sigma_factor=f), alias=dict(alias),
                                    fixed=0) for f in (1.0, 20.0)}
    err = {f: _max_errors(r.poses, lap["gt"])[0] for f, r in runs.items()}
    print(f"silhouettes at factor 1: {err[1.0]:.3f} m, at factor 20: {err[20.0]:.4f} m")
    assert {int(l) % 10000 for l in runs[20.0].landmark_ids.tolist()} & sil   # still in the BA
    assert err[20.0] < 0.25 * err[1.0]
