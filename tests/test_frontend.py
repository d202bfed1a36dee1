"""Front end: matching primitives, stereo matching, pose refinement, entropy, Tracker.

Generated cases have exact ground truth; one case runs real ORB on a real KITTI pair.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy.frontend import KeyframeData, Tracker, TrackingParams, match_stereo
from canopy.frontend.features import OrbExtractor, grid_select
from canopy.frontend.geometry import (PoseJacobianBuffer, differential_entropy, pose_information, project_stereo,
                                      rotation_angle,
                                      se3_exp, se3_inv, stereo_pose_jacobian)
from canopy.frontend import matching
from canopy.frontend.matching import (as_words, band_pairs, best_two, grid_pairs, grid_pairs_grouped, hamming_pairs,
                                      match_in_window, unique_by_reference)
from canopy.frontend.pose import refine_pose
from shared.errors import ConfigError
from shared.params import params_from_mapping
from shared.types import StereoCalibration, StereoFrame

CALIB = StereoCalibration(fx=400.0, fy=400.0, cx=320.0, cy=240.0, baseline=0.12, width=640, height=480)


def textured_image(rng, h, w, blur=1.5):
    img = rng.uniform(0, 255, (h, w)).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), blur)
    img = (img - img.min()) / (img.max() - img.min()) * 255
    return img.astype(np.uint8)


def random_points(rng, n, zmin=2.0, zmax=12.0):
    z = rng.uniform(zmin, zmax, n)
    u = rng.uniform(20, CALIB.width - 20, n)
    v = rng.uniform(20, CALIB.height - 20, n)
    return np.stack([(u - CALIB.cx) * z / CALIB.fx, (v - CALIB.cy) * z / CALIB.fy, z], axis=1)


# ------------------------------------------------------------------ primitives
def test_params_validate_and_from_mapping():
    p = params_from_mapping(TrackingParams, {"n_features": 500, "entropy_ratio_alpha": 0.7}, "test.yaml")
    assert p.n_features == 500 and p.entropy_ratio_alpha == 0.7
    with pytest.raises(ConfigError, match="entropy_ratio_alpha"):
        TrackingParams(entropy_ratio_alpha=1.5)
    with pytest.raises(ConfigError, match="unknown"):
        params_from_mapping(TrackingParams, {"n_feature": 5}, "test.yaml")


def test_hamming_matches_bitwise_reference():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    b[0], b[1] = ~a[0], a[1]               # the extremes: every bit differs (256), none does (0)
    ia, ib = rng.integers(0, 50, 200), rng.integers(0, 60, 200)
    ia[:2], ib[:2] = (0, 1), (0, 1)
    ref = np.unpackbits(a[ia] ^ b[ib], axis=1).sum(axis=1)
    dist = hamming_pairs(as_words(a), as_words(b), ia, ib)
    assert dist.dtype == np.int32 and dist[0] == 256 and dist[1] == 0
    np.testing.assert_array_equal(dist, ref)


def test_band_and_grid_pairs_match_brute_force():
    rng = np.random.default_rng(1)
    keys = np.sort(rng.uniform(0, 100, 300))
    lo = rng.uniform(0, 100, 40)
    hi = lo + rng.uniform(0, 5, 40)
    qi, rj = band_pairs(lo, hi, keys)
    brute = {(i, j) for i in range(40) for j in range(300) if lo[i] <= keys[j] <= hi[i]}
    assert set(zip(qi.tolist(), rj.tolist())) == brute
    q = rng.uniform(0, 640, (80, 2))
    r = rng.uniform(0, 640, (400, 2))
    qi, rj = grid_pairs(q, r, 20.0)
    got = set(zip(qi.tolist(), rj.tolist()))
    d = np.linalg.norm(q[:, None] - r[None], axis=2)
    within = {(i, j) for i, j in zip(*np.nonzero(d <= 20.0))}
    assert within <= got  # every pair inside the radius is a candidate


def test_best_two_and_window_matching():
    qi = np.array([0, 0, 0, 1, 1, 2])
    rj = np.array([5, 6, 7, 5, 8, 9])
    dist = np.array([30, 10, 20, 40, 41, 3])
    best, bd, sd = best_two(qi, rj, dist, 4)
    np.testing.assert_array_equal(best, [6, 5, 9, -1])
    np.testing.assert_array_equal(bd[:3], [10, 40, 3])
    np.testing.assert_array_equal(sd[:2], [20, 41])
    rng = np.random.default_rng(2)
    desc = rng.integers(0, 256, (100, 32), dtype=np.uint8)
    uv = rng.uniform(0, 600, (100, 2))
    q, r, _ = match_in_window(uv + 1.0, as_words(desc), np.full(100, 5.0), uv, as_words(desc), 50, 0.8)
    assert len(q) >= 95 and np.array_equal(q, r)


def test_window_ratio_test_only_between_candidates_on_one_level():
    """A landmark with two equally similar keypoints in its window is ambiguous when both sit on
    the same pyramid level, not when they are the same corner on two levels (ORB-SLAM)."""
    rng = np.random.default_rng(4)
    d = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    near = d.copy()
    near[0, 0] ^= 0b11111                               # 5 bits from the landmark's descriptor
    ref_desc = np.concatenate([d, near])
    ref_desc[0, 1] ^= 0b1111                            # best 4 bits, second 5: 4 >= 0.8 * 5
    uv_q = np.array([[100.0, 100.0]])
    uv_r = np.array([[101.0, 100.0], [99.0, 101.0]])
    args = (uv_q, as_words(d), np.array([5.0]), uv_r, as_words(ref_desc), 50, 0.8)
    assert len(match_in_window(*args)[0]) == 0                                    # ambiguous
    assert len(match_in_window(*args, r_level=np.array([0, 0]))[0]) == 0         # same level
    q, r, _ = match_in_window(*args, r_level=np.array([0, 1]))                    # two levels
    assert q.tolist() == [0] and r.tolist() == [0]


def _scaled_window_by_level_grids(q_uv, q_words, radius, r_uv, r_words, max_hamming, ratio, r_scale, r_level):
    """match_in_window's scaled search as it was: one grid per reference scale, ties to the earlier pair."""
    scales, group = np.unique(r_scale, return_inverse=True)
    qi, rj = grid_pairs_grouped(q_uv, r_uv, group.reshape(-1), radius * scales)
    d2 = ((q_uv[qi] - r_uv[rj]) ** 2).sum(axis=1)
    ok = d2 <= (radius * r_scale[rj]) ** 2
    qi, rj = qi[ok], rj[ok]
    dist = hamming_pairs(q_words, r_words, qi, rj)
    best, bd, sd, sr = best_two(qi, rj, dist, len(q_uv), second_ref=True)
    amb = (bd >= ratio * sd) & (sr >= 0) & (r_level[np.maximum(sr, 0)] == r_level[np.maximum(best, 0)])
    q = np.flatnonzero((best >= 0) & (bd <= max_hamming) & ~amb)
    keep = unique_by_reference(q, best[q], bd[q])
    return q[keep], best[q][keep], bd[q][keep]


@pytest.mark.parametrize("seed,bands", [(0, 3), (1, 3), (2, 3), (0, 1), (1, 2), (2, 8)])
def test_scaled_window_search_matches_one_grid_per_scale_despite_ties(seed, bands, monkeypatch):
    """The local-map search's one wide grid + grid-order tie ranks (match_in_window with r_scale)
    gives the matches of one grid per pyramid scale, also when most candidates tie: descriptors from
    a handful of patterns, so equal Hamming distances are the rule."""
    rng = np.random.default_rng(seed)
    n_q, n_r = 400, 900
    patterns = rng.integers(0, 256, (6, 32), dtype=np.uint8)
    r_desc = patterns[rng.integers(0, 6, n_r)].copy()
    r_desc[np.arange(n_r), rng.integers(0, 32, n_r)] ^= np.uint8(1)     # distances 0, 1, 2 ... tie often
    q_desc = patterns[rng.integers(0, 6, n_q)]
    r_uv = rng.uniform(0, [400, 150], (n_r, 2))
    q_uv = np.concatenate([r_uv[:n_q // 2] + rng.normal(0, 2, (n_q // 2, 2)), rng.uniform(-5, [405, 155], (n_q // 2, 2))])
    level = rng.integers(0, 8, n_r)
    scale = 1.2 ** level
    args = (q_uv, as_words(q_desc), np.full(n_q, 4.0), r_uv, as_words(r_desc), 50, 0.9)
    monkeypatch.setattr(matching, "SCALE_BANDS", bands)
    got = match_in_window(*args, r_scale=scale, r_level=level)
    want = _scaled_window_by_level_grids(q_uv, as_words(q_desc), 4.0, r_uv, as_words(r_desc), 50, 0.9, scale, level)
    assert len(want[0]) > 20
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)


def test_grid_select_spreads_features():
    rng = np.random.default_rng(3)
    uv = np.concatenate([rng.uniform(0, 100, (900, 2)), rng.uniform(100, 640, (100, 2))])
    resp = np.concatenate([np.full(900, 10.0), np.full(100, 1.0)])
    keep = grid_select(uv, resp, 640, 640, 200, 8, 8)
    assert len(keep) == 200
    assert (uv[keep, 0] >= 100).sum() >= 60  # weak but lonely corners survive bucketing


# ------------------------------------------------------------------ stereo matching
@pytest.mark.parametrize("disparity", [7.3, 24.6])
def test_stereo_matching_recovers_plane_depth(disparity):
    """Fronto-parallel textured plane: the right image is the left one shifted by d."""
    rng = np.random.default_rng(4)
    big = textured_image(rng, CALIB.height, CALIB.width + 64)
    M_left = np.float32([[1, 0, -32], [0, 1, 0]])
    M_right = np.float32([[1, 0, -32 - disparity], [0, 1, 0]])  # right(x) = left(x + d)
    size = (CALIB.width, CALIB.height)
    left = cv2.warpAffine(big, M_left, size, flags=cv2.INTER_LINEAR)
    right = cv2.warpAffine(big, M_right, size, flags=cv2.INTER_LINEAR)
    p = TrackingParams()
    ex = OrbExtractor(p)
    L, R = ex.extract(left), ex.extract(right)
    st = match_stereo(L, R, left, right, CALIB, p)
    ok = st.valid
    assert ok.sum() > 0.4 * len(L)
    disp = L.uv[ok, 0] - st.u_right[ok]
    err = np.abs(disp - disparity)
    # SAD + parabola refinement (ORB-SLAM2): ~0.2 px median; integer ORB corners alone put
    # only 40-60 % of the matches within 0.5 px for a fractional disparity
    assert np.median(err) < 0.25
    assert np.mean(err < 0.5) > 0.9
    # depth: the parabola fit on SAD pulls sub-pixel disparities towards the integer (pixel locking);
    # over 30 textures (seeds 0-29) the median disparity is 0.056-0.113 px short at 7.3 (depth +0.8 to
    # +1.6 %, the same on OpenCV 5.0 and 5.1) and within 0.034 px at 24.6, so the bound is a 0.15 px
    # median disparity bias as relative depth (2.1 % at 7.3, 0.6 % at 24.6); a 1 % bound failed
    # 16/30 textures at 7.3 on 5.0 and passed seed 4 there by 0.06 %, which 5.1's rounding of the
    # warped image's half-level ties (4 % of pixels differ by one grey level) took away
    depth_true = CALIB.bf / disparity
    assert abs(np.median(st.depth[ok]) - depth_true) / depth_true < 0.15 / disparity


# ------------------------------------------------------------------ geometry, refinement, entropy
def test_stereo_pose_jacobian_matches_central_differences():
    rng = np.random.default_rng(5)
    T_cw = se3_exp(np.array([0.05, -0.1, 0.02, 0.3, -0.2, 0.1]))
    X = transform_inv(T_cw, random_points(rng, 20))
    _, Pc = project_stereo(T_cw, X, CALIB)
    J = stereo_pose_jacobian(Pc, CALIB)
    eps = 1e-6
    Jn = np.zeros_like(J)
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        plus, _ = project_stereo(se3_exp(d) @ T_cw, X, CALIB)
        minus, _ = project_stereo(se3_exp(-d) @ T_cw, X, CALIB)
        Jn[:, :, k] = (plus - minus) / (2 * eps)
    np.testing.assert_allclose(J, Jn, rtol=1e-5, atol=1e-4)


def transform_inv(T_cw, Pc):
    T_wc = se3_inv(T_cw)
    return Pc @ T_wc[:3, :3].T + T_wc[:3, 3]


def test_refine_pose_recovers_exact_pose_and_flags_outliers():
    rng = np.random.default_rng(6)
    T_true = se3_exp(np.array([0.02, 0.1, -0.03, 0.5, 0.1, -0.2]))
    X = transform_inv(T_true, random_points(rng, 150))
    meas, _ = project_stereo(T_true, X, CALIB)
    meas[:10, :2] += rng.uniform(30, 60, (10, 2))  # gross outliers
    T0 = se3_exp(np.array([0.01, -0.01, 0.02, 0.05, -0.05, 0.08])) @ T_true
    est = refine_pose(T0, X, meas, np.ones(150, bool), np.ones(150), CALIB, 4, 10, 5.991, 7.815)
    assert not est.inliers[:10].any() and est.inliers[10:].all()
    err = se3_inv(T_true) @ est.T_cam_world
    assert np.linalg.norm(err[:3, 3]) < 1e-8 and rotation_angle(err[:3, :3]) < 1e-9


def test_refine_pose_stops_at_its_optimum_on_noisy_measurements():
    """Gauss-Newton stops once an applied step is below pose._CONVERGED_STEP (10 µrad / 10 µm): on
    a non-zero-residual problem (1 px noise, one plain least-squares round from 0.3 m / 3 deg away)
    the pose it returns is the optimum to < 1 nm (GN's error after a step of 1e-5 is of its square):
    refining on from it moves it by less. (A stop at 1e-3 leaves ~1e-7 m here and fails.)"""
    rng = np.random.default_rng(11)
    T_true = se3_exp(np.array([0.02, -0.05, 0.01, 0.3, -0.1, 0.4]))
    X = transform_inv(T_true, random_points(rng, 200))
    meas, _ = project_stereo(T_true, X, CALIB)
    meas += rng.normal(0.0, 1.0, meas.shape)
    T0 = se3_exp(np.array([0.05, -0.05, 0.03, 0.3, -0.2, 0.3])) @ T_true
    everyone = np.ones(200, bool)
    est = refine_pose(T0, X, meas, everyone, np.ones(200), CALIB, 1, 10, 5.991, 7.815)
    again = refine_pose(est.T_cam_world, X, meas, everyone, np.ones(200), CALIB, 1, 50, 5.991, 7.815,
                        inliers=everyone)
    moved = se3_inv(est.T_cam_world) @ again.T_cam_world
    assert np.linalg.norm(moved[:3, 3]) < 1e-9 and rotation_angle(moved[:3, :3]) < 1e-9
    assert np.linalg.norm((se3_inv(T0) @ est.T_cam_world)[:3, 3]) > 0.1  # it did move from the start


def test_pose_jacobian_buffer_equals_stereo_pose_jacobian_bit_for_bit():
    """The refinement's reused Jacobian buffers give stereo_pose_jacobian's values exactly, call after call."""
    rng = np.random.default_rng(8)
    buf = PoseJacobianBuffer(50)
    for _ in range(3):
        Pc = random_points(rng, 50)
        np.testing.assert_array_equal(buf(Pc, CALIB), stereo_pose_jacobian(Pc, CALIB))


def test_refine_pose_ignores_points_behind_the_camera():
    """Points behind the camera get zero weight (the masked rows of refine_pose) and end as outliers."""
    rng = np.random.default_rng(9)
    T_true = se3_exp(np.array([0.01, -0.02, 0.03, 0.2, 0.1, -0.1]))
    X = transform_inv(T_true, random_points(rng, 100))
    meas, _ = project_stereo(T_true, X, CALIB)
    Xb = X.copy()
    Xb[:5] = transform_inv(T_true, np.array([[0.5, 0.2, -3.0]] * 5))  # behind the camera
    T0 = se3_exp(np.array([0.005, 0.0, -0.005, 0.02, -0.02, 0.03])) @ T_true
    est = refine_pose(T0, Xb, meas, np.ones(100, bool), np.ones(100), CALIB, 4, 10, 5.991, 7.815)
    assert not est.inliers[:5].any() and est.inliers[5:].all() and np.isinf(est.chi2[:5]).all()
    err = se3_inv(T_true) @ est.T_cam_world
    assert np.linalg.norm(err[:3, 3]) < 1e-8


def test_entropy_eq6_and_ratio_falls_with_distance():
    cov = np.diag([1e-4, 2e-4, 3e-4, 1e-3, 2e-3, 3e-3])
    closed = 3 * (1 + np.log(2 * np.pi)) + 0.5 * np.log(np.prod(np.diag(cov)))  # AGRI Eq. 6
    assert differential_entropy(cov) == pytest.approx(closed)
    # Keyframe landmarks seen from cameras moving away from the keyframe: fewer visible
    # points, smaller disparities -> larger covariance -> Eq. 7 ratio falls below 1.
    rng = np.random.default_rng(7)
    X = random_points(rng, 400, 3.0, 10.0)
    ratios, H1 = [], None
    for j, dist in enumerate(np.linspace(0.1, 12.0, 12)):
        T_cw = se3_exp(np.array([0, 0.05 * dist, 0, 0.3 * dist, 0, dist]))  # backwards, sideways, turning
        meas, Pc = project_stereo(T_cw, X, CALIB)
        vis = (Pc[:, 2] > 0) & (meas[:, 0] > 0) & (meas[:, 0] < CALIB.width) & (meas[:, 1] > 0) & (meas[:, 1] < CALIB.height)
        info = pose_information(stereo_pose_jacobian(Pc[vis], CALIB), np.ones(vis.sum()), np.ones(vis.sum(), bool))
        H = differential_entropy(np.linalg.inv(info))
        H1 = H if H1 is None else H1
        ratios.append(H / H1)
    assert np.all(np.diff(ratios) < 0)
    assert ratios[-1] < TrackingParams().entropy_ratio_alpha


# ------------------------------------------------------------------ Tracker on rendered stereo sequences
def camera_rays(T_wc, calib, right=False):
    """World origin (3,) and per-pixel ray directions (H,W,3, unit z in the camera) of the left
    camera at ``T_wc``, or of the right one a baseline to its right."""
    T = T_wc.copy()
    if right:
        T = T @ np.array([[1, 0, 0, calib.baseline], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    u, v = np.meshgrid(np.arange(calib.width, dtype=np.float64), np.arange(calib.height, dtype=np.float64))
    rays = np.stack([(u - calib.cx) / calib.fx, (v - calib.cy) / calib.fy, np.ones_like(u)], axis=-1)
    return T[:3, 3], rays @ T[:3, :3].T


def render_wall(texture, T_wc, calib, wall_z=5.0, extent=6.0, right=False):
    """Render a textured plane Z = wall_z (world) seen from the (left or right) camera."""
    o, d = camera_rays(T_wc, calib, right)
    s = (wall_z - o[2]) / d[..., 2]
    P = o + s[..., None] * d
    h, w = texture.shape
    mx = ((P[..., 0] + extent) / (2 * extent) * (w - 1)).astype(np.float32)
    my = ((P[..., 1] + extent) / (2 * extent) * (h - 1)).astype(np.float32)
    return cv2.remap(texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def test_tracker_follows_rendered_sequence():
    rng = np.random.default_rng(8)
    texture = textured_image(rng, 1600, 1600, blur=2.0)
    n = 8
    poses = [se3_exp(np.array([0.0, 0.01 * i, 0.0, 0.04 * i, 0.01 * i, 0.05 * i])) for i in range(n)]
    tracker = Tracker(CALIB, TrackingParams())
    from canopy.backend import LocalMapper
    mapper = LocalMapper(CALIB)
    for i, T in enumerate(poses):
        frame = StereoFrame(i, 0.05 * i, render_wall(texture, T, CALIB), render_wall(texture, T, CALIB, right=True))
        res = tracker.track(frame)
        assert res.status in ("init", "ok")
        if res.is_keyframe:
            assert isinstance(res.keyframe, KeyframeData)
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
        err = se3_inv(T) @ res.T_world_cam
        assert np.linalg.norm(err[:3, 3]) < 0.01, i
        assert np.degrees(rotation_angle(err[:3, :3])) < 0.1, i


def test_real_kitti_frame_tracked_against_itself_gives_identity():
    from canopy.sources import open_source

    src = open_source("kitti", max_frames=1)
    f = src.frame(0)
    tracker = Tracker(src.calibration, TrackingParams())
    first = tracker.track(f)
    assert first.status == "init" and first.is_keyframe
    again = tracker.track(StereoFrame(1, f.timestamp + 0.1, f.left, f.right))
    assert again.status == "ok" and again.n_inliers > 100
    assert np.linalg.norm(again.T_world_cam[:3, 3]) < 1e-6
    assert rotation_angle(again.T_world_cam[:3, :3]) < 1e-7
    for key in ("orb", "stereo", "match_motion", "pnp", "track_local_map", "total"):
        assert key in again.timings


def test_adaptive_fast_fallback_recovers_corners_on_a_dark_frame():
    """AFE Eq. 18 then Eq. 19: a dark, flat frame gets the lower threshold."""
    import numpy as np

    from canopy.enhance import adaptive_fast_threshold, fallback_fast_threshold
    from canopy.frontend import OrbExtractor, TrackingParams
    from canopy.sources import open_source

    dark = (open_source("euroc").frame(0).left * 0.08).astype(np.uint8)
    hi, lo = adaptive_fast_threshold(dark), fallback_fast_threshold(dark)
    assert lo < hi
    ex = OrbExtractor(TrackingParams())
    only_eq18 = len(ex.extract(dark, hi))
    with_eq19 = len(ex.extract(dark, hi, lo, min_keypoints=200))
    assert only_eq18 < 200 <= with_eq19
    # enough corners: the fallback is not used
    bright = open_source("euroc").frame(0).left
    assert len(ex.extract(bright, 20, 1, min_keypoints=10).uv) == len(ex.extract(bright, 20).uv)


# ------------------------------------------------------------------ trust in a pose (issue 9)
def _wall_sequence(n, step=0.04):
    rng = np.random.default_rng(8)
    texture = textured_image(rng, 1600, 1600, blur=2.0)
    poses = [se3_exp(np.array([0.0, 0.0, 0.0, step * i, 0.0, 0.02 * i])) for i in range(n)]
    return texture, poses


def test_blank_frames_are_predicted_then_lost_with_a_reason_then_relocalised():
    from canopy.frontend import STATUS_LOST, STATUS_PREDICTED
    from canopy.frontend.track_health import LOST_REASONS

    texture, poses = _wall_sequence(9)
    tracker = Tracker(CALIB, TrackingParams(max_predicted_frames=2))
    blank = np.zeros((CALIB.height, CALIB.width), np.uint8)
    statuses, reasons = [], []
    for i, T in enumerate(poses):
        if 3 <= i <= 5:
            frame = StereoFrame(i, 0.05 * i, blank, blank)
        else:
            frame = StereoFrame(i, 0.05 * i, render_wall(texture, T, CALIB), render_wall(texture, T, CALIB, right=True))
        res = tracker.track(frame)
        statuses.append(res.status)
        reasons.append(res.lost_reason)
        if res.status == STATUS_PREDICTED:
            # the motion model continues the constant velocity: honest only for a short gap
            assert np.linalg.norm(res.T_world_cam[:3, 3] - T[:3, 3]) < 0.02, i
    assert statuses[:3] == ["init", "ok", "ok"]
    assert statuses[3:6] == [STATUS_PREDICTED, STATUS_PREDICTED, STATUS_LOST]
    assert all(r in LOST_REASONS for r in reasons[3:6]) and not any(reasons[:3])
    # relocalised into the same map (issue 10): no new segment, the pose is the true one again
    assert statuses[6:] == ["ok", "ok", "ok"]
    assert np.linalg.norm(res.T_world_cam[:3, 3] - poses[-1][:3, 3]) < 0.02
    assert tracker.n_lost == 1 and tracker.n_predicted == 2


def test_a_pose_far_from_the_motion_model_is_rejected():
    from canopy.frontend.track_health import (LOST_INCONSISTENT_MOTION, LOST_LOW_INLIER_FRACTION,
                                              LOST_TOO_FEW_INLIERS, judge_pose)

    p = TrackingParams()
    T_pred = se3_exp(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0]))
    near = se3_exp(np.array([0.0, 0.01, 0.0, 0.05, 0.0, 1.1]))
    jump = se3_exp(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0 + 2 * p.max_motion_deviation_m]))
    turn = se3_exp(np.array([0.0, np.radians(2 * p.max_motion_deviation_deg), 0.0, 0.0, 0.0, 1.0]))
    assert judge_pose(200, 250, near, T_pred, p, check_motion=True) == ""
    assert judge_pose(200, 250, jump, T_pred, p, check_motion=True) == LOST_INCONSISTENT_MOTION
    assert judge_pose(200, 250, turn, T_pred, p, check_motion=True) == LOST_INCONSISTENT_MOTION
    assert judge_pose(200, 250, jump, T_pred, p, check_motion=False) == ""  # no motion model yet
    assert judge_pose(p.min_inliers - 1, 250, near, T_pred, p, check_motion=True) == LOST_TOO_FEW_INLIERS
    assert judge_pose(30, 1000, near, T_pred, p, check_motion=True) == LOST_LOW_INLIER_FRACTION


def test_noise_estimate_and_noise_scaled_fast_threshold():
    from canopy.frontend.track_health import image_noise_sigma

    rng = np.random.default_rng(3)
    smooth = textured_image(rng, 480, 640, blur=6.0).astype(np.float64)
    for sigma in (4.0, 12.0):
        noisy = np.clip(smooth + rng.normal(0, sigma, smooth.shape), 0, 255).astype(np.uint8)
        assert abs(image_noise_sigma(noisy) - sigma) < 0.2 * sigma + 1.0, sigma
    # a noisy frame: the FAST threshold rises with the noise, so fewer corners come from noise
    noisy = np.clip(smooth + rng.normal(0, 15.0, smooth.shape), 0, 255).astype(np.uint8)
    on = Tracker(CALIB, TrackingParams(fast_noise_factor=3.0)).track(StereoFrame(0, 0.0, noisy, noisy))
    off = Tracker(CALIB, TrackingParams(fast_noise_factor=0.0)).track(StereoFrame(0, 0.0, noisy, noisy))
    assert on.noise_sigma is not None and 3.0 * on.noise_sigma > TrackingParams().fast_threshold
    assert "noise_estimate" in on.timings and off.noise_sigma is None


# ------------------------------------------------------------------ disparity offset of the rig
def test_disparity_offset_is_recovered_from_two_frames_without_ground_truth():
    from canopy.frontend.disparity_offset import estimate_disparity_offset

    rng = np.random.default_rng(5)
    P1 = random_points(rng, 400, 3.0, 40.0)
    T21 = se3_exp(np.array([0.0, 0.01, 0.0, 0.05, 0.0, -1.0]))  # forward 1 m
    P2 = P1 @ T21[:3, :3].T + T21[:3, 3]
    true_offset = 0.3

    def observe(P):
        pred, _ = project_stereo(np.eye(4), P, CALIB)
        d = pred[:, 0] - pred[:, 2] - true_offset + rng.normal(0, 0.1, len(P))
        return pred[:, :2] + rng.normal(0, 0.1, (len(P), 2)), d

    uv1, d1 = observe(P1)
    uv2, d2 = observe(P2)
    sig = np.ones(len(P1))
    delta, sd, T = estimate_disparity_offset(uv1, d1, sig, uv2, d2, sig, np.eye(4), CALIB)
    assert abs(delta - true_offset) < 0.05 and sd < 0.1
    assert np.linalg.norm(T[:3, 3] - T21[:3, 3]) < 0.01
    # no motion: the offset cancels and the estimate says so
    _, sd_static, _ = estimate_disparity_offset(uv1, d1, sig, uv1, d1, sig, np.eye(4), CALIB)
    assert not sd_static < 1.0
    # the configured offset moves every disparity (match_stereo)
    img = textured_image(rng, CALIB.height, CALIB.width)
    right = np.roll(img, -8, axis=1)
    ex = OrbExtractor(TrackingParams())
    L, R = ex.extract(img), ex.extract(right)
    a = match_stereo(L, R, img, right, CALIB, TrackingParams())
    b = match_stereo(L, R, img, right, CALIB, TrackingParams(disparity_offset_px=0.5))
    both = a.valid & b.valid
    assert both.sum() > 50
    np.testing.assert_allclose((L.uv[both, 0] - b.u_right[both]) - (L.uv[both, 0] - a.u_right[both]), 0.5, atol=1e-3)
