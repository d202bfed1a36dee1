"""The camera's up from vertical segments (canopy.lines.vertical) on generated scenes with exact ground truth.

Scene: planar posts with exactly vertical side edges (world z up) and horizontal rails between them, seen by a
camera pitched and rolled by known angles, rendered at 4x resolution and area-averaged down, on a noisy
background. The true up in the camera frame is R_world_camᵀ e_z.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy.lines.vertical import (VerticalParams, estimate_vertical, estimate_vertical_from_segments,
                                   interpretation_normals, refine_segments_subpixel)
from shared.errors import ConfigError, InputError

W, H = 752, 480
K = np.array([[435.0, 0.0, 375.5], [0.0, 435.0, 239.5], [0.0, 0.0, 1.0]])
SUPERSAMPLE = 8
# camera at heading 0 (as canopy.synthetic.trajectories.R_BASE): x_cam = -y_world, y_cam = -z_world, z_cam = x_world
R_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _rot(axis: int, deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def camera(pitch_deg: float, roll_deg: float):
    """(R_world_cam, camera centre): pitched about camera x, rolled about camera z, 1.2 m above the ground."""
    R_wc = R_BASE @ _rot(0, pitch_deg) @ _rot(2, roll_deg)
    return R_wc, np.array([0.0, 0.0, 1.2])


def _project(Pw, R_wc, c):
    Pc = (Pw - c) @ R_wc  # R_wcᵀ (P - c), row-wise
    uvw = Pc @ K.T
    return uvw[:, :2] / uvw[:, 2:3]


def _posts_and_rails():
    """World quads (4 corners each) and grey values: posts 0.12 m wide (vertical edges), rails between them."""
    quads = []
    for k, (x, y) in enumerate([(4, 1.5), (5, -1.2), (6.5, 2.2), (7, -2.0), (9, 0.6), (10, -0.8), (12, 2.5),
                                (14, -2.6)]):
        quads.append((np.array([[x, y - 0.06, 0], [x, y + 0.06, 0], [x, y + 0.06, 1.8], [x, y - 0.06, 1.8]]),
                      40 + 25 * (k % 4)))
    for y in (1.5, -1.5):  # rails along the viewing direction: converge to the horizon, not to up
        for z in (0.5, 1.0):
            quads.append((np.array([[3, y, z], [15, y, z], [15, y, z + 0.04], [3, y, z + 0.04]]), 220))
    return quads


def render(R_wc, c, seed=0, noise=3.0, quads=None):
    rng = np.random.default_rng(seed)
    s = SUPERSAMPLE
    hi = np.full((H * s, W * s), 120, np.uint8)
    for corners, value in quads if quads is not None else _posts_and_rails():
        uv = _project(corners, R_wc, c)
        pts = np.round(((uv + 0.5) * s - 0.5) * 16).astype(np.int32)
        cv2.fillConvexPoly(hi, pts, int(value), lineType=cv2.LINE_8, shift=4)
    img = cv2.resize(hi, (W, H), interpolation=cv2.INTER_AREA).astype(np.float32)
    img += rng.normal(0.0, noise, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


@pytest.mark.parametrize("pitch, roll", [(-6.0, 0.0), (4.0, -3.0), (-10.0, 8.0)])
def test_up_of_a_rendered_post_scene_within_a_third_of_a_degree(pitch, roll):
    R_wc, c = camera(pitch, roll)
    up_true = R_wc.T @ np.array([0.0, 0.0, 1.0])
    img = render(R_wc, c, seed=1)
    for prior in (None, up_true):  # the upright gate (±30 deg) and a predicted up
        est = estimate_vertical(img, K, prior)
        assert est is not None
        assert est.up_cam[1] < 0 and abs(np.linalg.norm(est.up_cam) - 1) < 1e-9
        assert angle_deg(est.up_cam, up_true) < 0.3
        assert est.n_inliers >= 8  # two edges per visible post
        assert 0 < est.sigma_deg < 0.5


def test_the_gate_keeps_the_search_near_the_prediction():
    R_wc, c = camera(-6.0, 2.0)
    img = render(R_wc, c, seed=2)
    up_true = R_wc.T @ np.array([0.0, 0.0, 1.0])
    tilt = np.cross(up_true, [1.0, 0.0, 0.0])
    tilt /= np.linalg.norm(tilt)

    def off(deg):
        return np.cos(np.radians(deg)) * up_true + np.sin(np.radians(deg)) * tilt

    # a prediction 3 deg off still finds the true up (the gate is 5 deg) ...
    est = estimate_vertical(img, K, off(3.0), VerticalParams(max_prior_deg=5.0))
    assert est is not None and angle_deg(est.up_cam, up_true) < 0.3
    # ... one 10 deg off finds nothing: the true up is outside the gate and no other direction explains 4 segments
    assert estimate_vertical(img, K, off(10.0), VerticalParams(max_prior_deg=5.0)) is None
    # predicted along the rails (world x), the rails' own vanishing direction is what is found, not up
    forward = R_wc.T @ np.array([1.0, 0.0, 0.0])
    est = estimate_vertical(img, K, forward, VerticalParams(max_prior_deg=5.0))
    assert est is not None and angle_deg(est.up_cam, -forward if forward[1] > 0 else forward) < 0.5
    assert angle_deg(est.up_cam, up_true) > 80


def test_subpixel_refit_puts_a_segment_on_its_edge():
    """A slanted step edge (known line) rendered at 16x and area-averaged, plus noise; a segment 0.6 px off it
    and 0.5 deg off its angle is moved onto the edge within 0.06 px at both ends."""
    rng = np.random.default_rng(5)
    s, h, w = 16, 200, 120
    a, b = np.radians(3.0), 60.3  # the edge: x = b + tan(a) * (y - 100)
    yy, xx = np.mgrid[0:h * s, 0:w * s]
    x_edge = b + np.tan(a) * ((yy + 0.5) / s - 0.5 - 100)
    hi = np.where((xx + 0.5) / s - 0.5 < x_edge, 60.0, 170.0)
    img = hi.reshape(h, s, w, s).mean(axis=(1, 3)) + rng.normal(0, 2.0, (h, w))
    img = np.clip(img, 0, 255).astype(np.uint8)

    def x_of(y):
        return b + np.tan(a) * (y - 100)

    seg = np.array([[x_of(20) + 0.6, 20.0, x_of(180) + 0.6 + 160 * np.tan(np.radians(0.5)), 180.0]])
    out = refine_segments_subpixel(img, seg)[0]
    for x, y in (out[:2], out[2:]):
        assert abs((x - x_of(y)) * np.cos(a)) < 0.06
    assert np.hypot(*(out[2:] - out[:2])) == pytest.approx(np.hypot(*(seg[0, 2:] - seg[0, :2])), abs=0.5)


def test_synthesised_segments_with_outliers():
    """Segments projected from known 3-D vertical lines (pixel noise 0.3 px) and random outlier segments."""
    rng = np.random.default_rng(3)
    R_wc, c = camera(-8.0, 5.0)
    up_true = R_wc.T @ np.array([0.0, 0.0, 1.0])
    base = np.column_stack([rng.uniform(3, 15, 30), rng.uniform(-4, 4, 30), np.zeros(30)])
    tops = base + np.array([0.0, 0.0, 1.5])
    segs = np.hstack([_project(base, R_wc, c), _project(tops, R_wc, c)]) + rng.normal(0, 0.3, (30, 4))
    centre = rng.uniform([50, 50], [700, 430], (30, 2))
    ang = rng.uniform(0, np.pi, 30)
    half = rng.uniform(10, 60, 30)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    outliers = np.hstack([centre - half, centre + half])
    est = estimate_vertical_from_segments(np.vstack([segs, outliers]), K)
    assert est is not None and angle_deg(est.up_cam, up_true) < 0.3
    assert 25 <= est.n_inliers <= 34  # the 30 verticals and at most a few outliers that pass by chance


def test_interpretation_normals_are_orthogonal_to_the_segment_rays():
    segs = np.array([[10.0, 20.0, 300.0, 400.0], [700.0, 5.0, 20.0, 470.0]])
    n = interpretation_normals(segs, K)
    Kinv = np.linalg.inv(K)
    for (x1, y1, x2, y2), ni in zip(segs, n):
        for x, y in ((x1, y1), (x2, y2)):
            assert abs(ni @ (Kinv @ [x, y, 1.0])) < 1e-12
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)


def test_none_without_vertical_structure():
    R_wc, c = camera(-6.0, 0.0)
    rails_only = [q for q in _posts_and_rails() if q[1] == 220]
    assert estimate_vertical(render(R_wc, c, quads=rails_only), K) is None
    assert estimate_vertical(np.full((H, W), 90, np.uint8), K) is None


def test_bad_input_raises_a_clear_error():
    img = np.full((H, W), 90, np.uint8)
    with pytest.raises(InputError, match="3x3"):
        estimate_vertical(img, np.eye(2))
    with pytest.raises(InputError, match="pinhole"):
        estimate_vertical(img, np.diag([435.0, -435.0, 1.0]))
    with pytest.raises(InputError, match="uint8"):
        estimate_vertical(img.astype(np.float32), K)
    with pytest.raises(InputError, match="prior_up_cam"):
        estimate_vertical(img, K, np.zeros(3))
    with pytest.raises(ConfigError, match="max_prior_deg"):
        VerticalParams(max_prior_deg=0.0)
    with pytest.raises(ConfigError, match="min_inliers"):
        VerticalParams(min_inliers=2)
    with pytest.raises(ConfigError, match="detector"):
        VerticalParams(detector="edlines")
