"""Line features: detection, LBD, stereo line matching / triangulation, Eq. 10 and its Jacobians.

The generated stereo pair has exact geometry: leaning posts (planar quads in 3D) rendered
at 4x resolution into both rectified images and area-averaged down, on a noisy background.
Their long side edges are the ground-truth 3D segments.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy.frontend.geometry import se3_exp, transform
from canopy.lines import (LineDescriber, LineParams, detect_segments, line_coefficients, line_reprojection_error,
                          line_reprojection_jacobians, line_residuals, match_stereo_lines, right_segments_in_reach,
                          sanitize_segments)
from shared.errors import ConfigError, InputError
from shared.params import params_from_mapping
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.25, width=752, height=480)
SUPERSAMPLE = 4


def _post_corners(x, y_bottom, z, width, height, lean_x, lean_z):
    """3D corners of a planar post (bottom-left, bottom-right, top-right, top-left)."""
    b = np.array([x, y_bottom, z])
    top = b + np.array([lean_x, -height, lean_z])
    half = np.array([width / 2, 0.0, 0.0])
    return np.array([b - half, b + half, top + half, top - half])


def _project(P, shift_x):
    u = CALIB.fx * (P[:, 0] - shift_x) / P[:, 2] + CALIB.cx
    v = CALIB.fy * P[:, 1] / P[:, 2] + CALIB.cy
    return np.column_stack([u, v])


def _render(posts, shift_x, rng):
    s = SUPERSAMPLE
    hi = np.full((CALIB.height * s, CALIB.width * s), 110, np.uint8)
    for corners, value in sorted(posts, key=lambda p: -p[0][:, 2].mean()):  # far to near
        uv = _project(corners, shift_x)
        pts = np.round(((uv + 0.5) * s - 0.5) * 16).astype(np.int32)  # 4 fractional bits
        cv2.fillConvexPoly(hi, pts, int(value), lineType=cv2.LINE_8, shift=4)
    img = cv2.resize(hi, (CALIB.width, CALIB.height), interpolation=cv2.INTER_AREA).astype(np.float32)
    img += rng.normal(0.0, 3.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    posts = []
    specs = [  # image column of the base, y_bottom, z, width, height, lean_x, lean_z, intensity
        (80, 1.2, 4.0, 0.25, 2.0, 0.15, 0.3, 30),
        (185, 1.0, 3.0, 0.20, 1.6, -0.10, -0.3, 200),
        (290, 1.3, 5.0, 0.30, 2.4, 0.20, 0.0, 60),
        (385, 0.9, 2.5, 0.15, 1.4, 0.0, 0.4, 235),
        (490, 1.2, 4.5, 0.30, 2.2, -0.20, -0.2, 15),
        (585, 1.0, 3.5, 0.20, 1.8, 0.10, 0.2, 175),
        (675, 1.4, 6.0, 0.40, 2.6, -0.2, 0.5, 80),
    ]
    gt = []
    for u0, yb, z, w, h, lx, lz, val in specs:
        x = (u0 - CALIB.cx) * z / CALIB.fx
        c = _post_corners(x, yb, z, w, h, lx, lz)
        posts.append((c, val))
        gt += [(c[0], c[3]), (c[1], c[2])]  # the two long side edges
    left = _render(posts, 0.0, rng)
    right = _render(posts, CALIB.baseline, rng)
    return left, right, np.array(gt)  # gt: (S,2,3)


def _point_line_dist3(P, A, B):
    d = (B - A) / np.linalg.norm(B - A)
    r = P - A
    return np.linalg.norm(r - (r @ d)[..., None] * d, axis=-1)


# ------------------------------------------------------------------ params
def test_params_validate_and_from_mapping():
    p = params_from_mapping(LineParams, {"detector": "lsd", "max_lines": 100}, "lines.yaml")
    assert p.detector == "lsd" and p.max_lines == 100
    with pytest.raises(ConfigError):
        LineParams(detector="edlines")
    with pytest.raises(ConfigError):
        LineParams(min_vertical_overlap=0.0)
    with pytest.raises(ConfigError):
        LineParams(lbd_band_width=4)


# ------------------------------------------------------------------ detection
@pytest.mark.parametrize("detector", ["fld", "lsd"])
def test_detected_segments_match_projections(scene, detector):
    left, _, gt = scene
    params = LineParams(detector=detector)
    segs, stats = detect_segments(left, params)
    assert segs.dtype == np.float32 and segs.shape[1] == 4 and stats["kept"] == len(segs)
    found = 0
    for A, B in gt:
        ab = _project(np.stack([A, B]), 0.0)
        l = line_coefficients(ab.reshape(1, 4))[0]
        dist = np.abs(np.column_stack([segs[:, :2], np.ones(len(segs))]) @ l)
        dist2 = np.abs(np.column_stack([segs[:, 2:], np.ones(len(segs))]) @ l)
        on_line = (dist < 1.0) & (dist2 < 1.0)
        # covered fraction of the projected edge along its direction
        t_dir = (ab[1] - ab[0]) / np.linalg.norm(ab[1] - ab[0])
        L = np.linalg.norm(ab[1] - ab[0])
        cover = 0.0
        for s in segs[on_line]:
            t = np.sort([(s[:2] - ab[0]) @ t_dir, (s[2:] - ab[0]) @ t_dir])
            cover = max(cover, (min(t[1], L) - max(t[0], 0.0)) / L)
        found += cover > 0.7
    assert found >= 0.9 * len(gt), f"{detector}: {found}/{len(gt)} edges detected"


def test_max_lines_keeps_longest(scene):
    left, _, _ = scene
    all_segs, _ = detect_segments(left, LineParams())
    few, stats = detect_segments(left, LineParams(max_lines=5))
    assert len(few) == 5 and stats["capped"] == len(all_segs) - 5
    L = np.hypot(*(few[:, 2:] - few[:, :2]).T)
    assert np.all(np.diff(L) <= 1e-4)
    assert L[-1] >= np.sort(np.hypot(*(all_segs[:, 2:] - all_segs[:, :2]).T))[-5] - 1e-4


# ------------------------------------------------------------------ degenerate input
def test_sanitize_counts_degenerate_segments():
    segs = np.array([
        [10, 10, 100, 200],           # good
        [np.nan, 10, 100, 200],       # nan
        [50, 50, 50, 50],             # zero length
        [-20, 10, 100, 200],          # outside
        [10, 10, 100, 500],           # outside (below)
        [10, 10, 12, 12],             # short
        [np.inf, 1, 2, 3],            # nan (non-finite)
    ], np.float64)
    kept, idx, counts = sanitize_segments(segs, 752, 480, min_length=18.0)
    assert idx.tolist() == [0] and kept.shape == (1, 4)
    assert counts == {"nan": 2, "zero_length": 1, "outside": 2, "short": 1}
    kept, idx, counts = sanitize_segments(np.zeros((0, 4)), 752, 480, 18.0)
    assert len(kept) == 0 and sum(counts.values()) == 0


@pytest.mark.parametrize("detector", ["fld", "lsd"])
def test_degenerate_images_never_crash(detector):
    params = LineParams(detector=detector)
    rng = np.random.default_rng(1)
    for img in (np.zeros((480, 752), np.uint8), np.full((3, 3), 255, np.uint8),
                rng.integers(0, 256, (60, 80), dtype=np.uint8), np.zeros((480, 752, 3), np.uint8)):
        segs, stats = detect_segments(img, params)
        desc = LineDescriber(params)(img if img.ndim == 2 else img[..., 0], segs)
        assert len(desc) == len(segs) == stats["kept"]
        m = match_stereo_lines(segs, desc, segs, desc, CALIB, params)
        assert len(m) == 0 or np.isfinite(m.points_cam).all()
    with pytest.raises(InputError):
        detect_segments(np.zeros((0, 0), np.uint8), params)
    with pytest.raises(InputError):
        detect_segments(np.zeros((10, 10), np.float32), params)


def test_matching_rejects_horizontal_and_empty():
    params = LineParams()
    desc = np.zeros((2, 32), np.uint8)
    horiz_l = np.array([[100, 200, 300, 205], [100, 300, 300, 300]], np.float32)
    horiz_r = horiz_l - np.array([20, 0, 20, 0], np.float32)
    m = match_stereo_lines(horiz_l, desc, horiz_r, desc, CALIB, params)
    assert len(m) == 0 and m.stats["horizontal"] == 2
    m = match_stereo_lines(np.zeros((0, 4)), np.zeros((0, 32), np.uint8), horiz_r, desc, CALIB, params)
    assert len(m) == 0


# ------------------------------------------------------------------ stereo
@pytest.mark.parametrize("detector", ["fld", "lsd"])
def test_stereo_triangulation_recovers_endpoints(scene, detector):
    left, right, gt = scene
    params = LineParams(detector=detector)
    describe = LineDescriber(params)
    sl, _ = detect_segments(left, params)
    sr, _ = detect_segments(right, params)
    m = match_stereo_lines(sl, describe(left, sl), sr, describe(right, sr), CALIB, params)
    assert len(m) >= 0.8 * len(gt), m.stats
    P = m.points_cam.reshape(-1, 3)
    # each endpoint lies on a true 3D edge within 1 % of its depth
    d = np.stack([_point_line_dist3(P, A, B) for A, B in gt], axis=1)
    edge = d.argmin(axis=1)
    assert np.all(d.min(axis=1) <= 0.01 * P[:, 2]), np.max(d.min(axis=1) / P[:, 2])
    # both endpoints of a match on the same edge, inside its extent (+ 3 % slack)
    edge = edge.reshape(-1, 2)
    assert np.all(edge[:, 0] == edge[:, 1])
    A, B = gt[edge[:, 0], 0], gt[edge[:, 0], 1]
    for k in range(2):
        t = np.einsum("ij,ij->i", m.points_cam[:, k] - A, B - A) / np.einsum("ij,ij->i", B - A, B - A)
        assert np.all((t > -0.03) & (t < 1.03))
    # distinct edges recovered
    assert len(np.unique(edge[:, 0])) >= 0.8 * len(gt)
    assert np.all(m.overlap >= params.min_vertical_overlap)


def test_real_euroc_frame_stereo_lines():
    from canopy.sources import open_source

    src = open_source("euroc")
    frame = src.frame(0)
    params = LineParams()
    describe = LineDescriber(params)
    sl, stats = detect_segments(frame.left, params)
    sr, _ = detect_segments(frame.right, params)
    m = match_stereo_lines(sl, describe(frame.left, sl), sr, describe(frame.right, sr), src.calibration, params)
    assert len(m) >= 50, m.stats
    # rectified rows: the matched right segment spans the same rows as the left one
    assert np.median(m.overlap) >= 0.9
    z = m.points_cam[:, :, 2]
    assert np.all(z > 0) and 0.5 < np.median(z) < 10.0  # an indoor room (Vicon room 1)
    # the back-projection reproduces the left endpoints
    seg = sl[m.left_idx]
    P = m.points_cam
    u = src.calibration.fx * P[..., 0] / P[..., 2] + src.calibration.cx
    v = src.calibration.fy * P[..., 1] / P[..., 2] + src.calibration.cy
    assert np.allclose(np.stack([u, v], -1).reshape(-1, 4), seg, atol=1e-3)


def test_right_segments_out_of_reach_never_match():
    """Describing only the right segments within stereo reach of a left one (what tracking does
    for the right image) gives exactly the matches of describing them all."""
    from canopy.sources import open_source

    src = open_source("euroc")
    frame = src.frame(0)
    params = LineParams()
    describe = LineDescriber(params)
    sl, _ = detect_segments(frame.left, params)
    sr, _ = detect_segments(frame.right, params)
    dl = describe(frame.left, sl)
    full = match_stereo_lines(sl, dl, sr, describe(frame.right, sr), src.calibration, params)
    keep = right_segments_in_reach(sl, sr, src.calibration, params)
    assert 0 < keep.sum() < len(sr)
    sub = match_stereo_lines(sl, dl, sr[keep], describe(frame.right, sr[keep]), src.calibration, params)
    np.testing.assert_array_equal(sub.left_idx, full.left_idx)
    np.testing.assert_array_equal(np.flatnonzero(keep)[sub.right_idx], full.right_idx)
    np.testing.assert_array_equal(sub.points_cam, full.points_cam)


# ------------------------------------------------------------------ Eq. 10 and Jacobians
def _random_case(rng):
    T = se3_exp(rng.normal(0, [0.2, 0.2, 0.2, 0.5, 0.5, 0.5]))
    Tinv = np.linalg.inv(T)
    Pc = np.column_stack([rng.uniform(-1, 1, 2), rng.uniform(-1, 1, 2), rng.uniform(2, 6, 2)])
    A_w, B_w = transform(Tinv, Pc)
    # observed line: projections of slightly different camera points
    obs = Pc + rng.normal(0, 0.05, Pc.shape)
    uv = np.column_stack([CALIB.fx * obs[:, 0] / obs[:, 2] + CALIB.cx, CALIB.fy * obs[:, 1] / obs[:, 2] + CALIB.cy])
    return T, A_w, B_w, line_coefficients(uv.reshape(1, 4))[0]


def test_line_reprojection_error_is_pixel_distance():
    rng = np.random.default_rng(3)
    T, A, B, l = _random_case(rng)
    e = line_reprojection_error(T, A, B, l, CALIB)
    Pc = transform(T, np.stack([A, B]))
    uv = np.column_stack([CALIB.fx * Pc[:, 0] / Pc[:, 2] + CALIB.cx, CALIB.fy * Pc[:, 1] / Pc[:, 2] + CALIB.cy])
    n = l[:2] / np.linalg.norm(l[:2])
    p0 = -l[2] * n  # closest point of the line to the origin
    assert np.allclose(e, (uv - p0) @ n, atol=1e-9)
    assert abs(np.linalg.norm(l[:2]) - 1) < 1e-12
    # zero on the exact projection
    uv_exact = uv.reshape(1, 4)
    assert np.allclose(line_reprojection_error(T, A, B, line_coefficients(uv_exact)[0], CALIB), 0, atol=1e-9)


def test_line_jacobians_against_central_differences():
    rng = np.random.default_rng(5)
    h = 1e-6
    for _ in range(5):
        T, A, B, l = _random_case(rng)
        J_pose, J_pts = line_reprojection_jacobians(T, A, B, l, CALIB)
        num_pose = np.zeros((2, 6))
        for k in range(6):
            dx = np.zeros(6)
            dx[k] = h
            num_pose[:, k] = (line_reprojection_error(se3_exp(dx) @ T, A, B, l, CALIB)
                              - line_reprojection_error(se3_exp(-dx) @ T, A, B, l, CALIB)) / (2 * h)
        num_pts = np.zeros((2, 6))
        for k in range(6):
            d = np.zeros(6)
            d[k] = h
            num_pts[:, k] = (line_reprojection_error(T, A + d[:3], B + d[3:], l, CALIB)
                             - line_reprojection_error(T, A - d[:3], B - d[3:], l, CALIB)) / (2 * h)
        assert np.allclose(J_pose, num_pose, rtol=1e-5, atol=1e-4), (J_pose, num_pose)
        assert np.allclose(J_pts, num_pts, rtol=1e-5, atol=1e-4), (J_pts, num_pts)


def test_batched_residuals_match_single():
    rng = np.random.default_rng(9)
    cases = [_random_case(rng) for _ in range(4)]
    T = cases[0][0]
    A = np.stack([c[1] for c in cases])
    B = np.stack([c[2] for c in cases])
    L = np.stack([c[3] for c in cases])
    e, J_pose, J_A, J_B = line_residuals(T, A, B, L, CALIB, jacobians=True)
    for i in range(4):
        assert np.allclose(e[i], line_reprojection_error(T, A[i], B[i], L[i], CALIB))
        jp, jx = line_reprojection_jacobians(T, A[i], B[i], L[i], CALIB)
        assert np.allclose(J_pose[i], jp) and np.allclose(J_A[i], jx[0, :3]) and np.allclose(J_B[i], jx[1, 3:])


def test_a_longer_view_extends_a_line_landmark():
    """Issue 4 item 3: the landmark holds the middle of a post; a view of the whole post
    extends it to the true endpoints; a partial view never shortens it."""
    from canopy.lines.geometry import extend_segment
    from shared.types import StereoCalibration

    calib = StereoCalibration(435.0, 435.0, 376.0, 240.0, 0.11, 752, 480)
    top, bottom = np.array([0.5, -1.0, 5.0]), np.array([0.6, 1.0, 5.5])  # true 3D post, world = camera 0
    A, B = top + 0.3 * (bottom - top), top + 0.6 * (bottom - top)      # the landmark: its middle only
    T_wc = np.eye(4)
    T_wc[:3, 3] = [0.3, 0.1, -0.5]  # a second viewpoint

    def project(X):
        Pc = X - T_wc[:3, 3]
        return np.array([calib.fx * Pc[0] / Pc[2] + calib.cx, calib.fy * Pc[1] / Pc[2] + calib.cy])

    full = np.concatenate([project(top), project(bottom)])
    A2, B2 = extend_segment(A, B, full, T_wc, calib, max_growth=2.0)
    np.testing.assert_allclose(A2, top, atol=1e-9)
    np.testing.assert_allclose(B2, bottom, atol=1e-9)
    partial = np.concatenate([project(top + 0.4 * (bottom - top)), project(top + 0.5 * (bottom - top))])
    A3, B3 = extend_segment(A, B, partial, T_wc, calib)
    np.testing.assert_allclose(A3, A) and np.testing.assert_allclose(B3, B)
    capped = extend_segment(A, B, full, T_wc, calib, max_growth=0.5)  # growth per update is bounded
    assert np.linalg.norm(capped[1] - capped[0]) <= 2.0 * np.linalg.norm(B - A) + 1e-9
