"""The ORB-SLAM-style cell extractor (canopy.frontend.cell_extractor, tracking.extractor: cells)."""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.frontend.cell_extractor import (CellExtractor, _best_ranks, _descending_key, harris_responses, ic_angles, level_quotas,
                                            make_extractor, quadtree_select)
from canopy.frontend.features import OrbExtractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import match_stereo
from canopy.frontend.track_health import image_noise_sigma
from canopy.sources import open_source
from shared.errors import ConfigError


@pytest.fixture(scope="module")
def kitti_pair():
    src = open_source("kitti", max_frames=1)
    f = src.frame(0)
    return f.left, f.right, src.calibration


@pytest.fixture(scope="module")
def kitti_params():
    return load_run_config("kitti").tracking  # 2000 features


def occupied_cells(uv: np.ndarray, w: int, h: int, cols: int = 40, rows: int = 12) -> int:
    c = np.clip((uv[:, 0] * cols / w).astype(int), 0, cols - 1) + cols * np.clip((uv[:, 1] * rows / h).astype(int),
                                                                                  0, rows - 1)
    return len(np.unique(c))


def test_level_quotas_follow_orbslam_and_add_up():
    q = level_quotas(2000, 1.2, 8)
    assert q.sum() == 2000
    assert q[0] == round(2000 * (1 - 1 / 1.2) / (1 - 1.2 ** -8))  # 434
    assert np.all(np.diff(q) < 0)  # each level 1/1.2 of the one below


def test_keypoints_spread_over_cells_on_a_kitti_image(kitti_pair, kitti_params):
    left, _, _ = kitti_pair
    cells = CellExtractor(replace(kitti_params, extractor="cells")).extract(left)
    cv = OrbExtractor(kitti_params).extract(left)
    h, w = left.shape
    assert len(cells) > 0.9 * kitti_params.n_features
    assert cells.extractor == "cells" and cv.extractor == "opencv"
    n_cells, n_cv = occupied_cells(cells.uv, w, h), occupied_cells(cv.uv, w, h)
    # measured: 190 of a 40x12 grid's 480 cells hold a corner, 133 with cv2.ORB + grid bucketing
    assert n_cells >= 1.3 * n_cv, (n_cells, n_cv)
    # every level has its quota's worth (ORB-SLAM's n (1 - f) f^l / (1 - f^L))
    counts = np.bincount(cells.octave, minlength=kitti_params.n_levels)
    quotas = level_quotas(kitti_params.n_features, kitti_params.scale_factor, kitti_params.n_levels)
    assert np.all(counts <= quotas) and counts[0] == quotas[0]


def low_contrast_image() -> np.ndarray:
    """Left half: bright squares on grey (contrast 80); right half: squares 14 grey levels above
    the background, which FAST at threshold 20 cannot see."""
    img = np.full((240, 480), 100, np.uint8)
    for y in range(30, 210, 30):
        for x in range(30, 450, 30):
            img[y:y + 12, x:x + 12] = 180 if x < 240 else 114
    return cv2.GaussianBlur(img, (0, 0), 1.0)  # a camera's blur (sharp plateaus defeat FAST's suppression)


def test_fallback_threshold_finds_corners_in_low_contrast_cells():
    img = low_contrast_image()
    p = TrackingParams(n_features=500, n_levels=1, extractor="cells")
    fast20 = cv2.FastFeatureDetector_create(20, True).detect(img[:, 260:])
    assert len(fast20) == 0  # the right half has nothing at 20
    f = CellExtractor(p).extract(img)
    right = f.uv[:, 0] > 260
    assert right.sum() >= 40, right.sum()
    assert (~right).sum() >= 40
    # ... and cv2.ORB with one threshold keeps none there
    cv = OrbExtractor(replace(p, extractor="opencv")).extract(img)
    assert (cv.uv[:, 0] > 260).sum() == 0


def test_fallback_threshold_stays_above_twice_the_noise():
    rng = np.random.default_rng(0)
    img = np.clip(low_contrast_image() + rng.normal(0, 8, (240, 480)), 0, 255).astype(np.uint8)
    p = TrackingParams(n_features=500, n_levels=1, extractor="cells")
    ex = CellExtractor(p)
    low, sigma = ex.fallback_for(img, None)
    assert sigma == pytest.approx(image_noise_sigma(img))
    assert sigma > 6 and low >= 2 * sigma
    # with the noise floor off (tracking.fast_noise_factor 0) ORB-SLAM's 7
    assert CellExtractor(replace(p, fast_noise_factor=0.0)).fallback_for(img, None) == (7, None)
    # an explicit fallback (AFE Eq. 19 on enhanced frames) is floored the same way
    assert CellExtractor(replace(p, extractor_enhanced="cells")).fallback_for(img, 3)[0] >= 2 * sigma


def test_a_given_noise_sigma_is_used_instead_of_measuring_it_again():
    """The tracker measures the left image's sigma for its FAST floor and hands it over: the
    same sigma gives the same features; a different one is the one that sets the floor."""
    rng = np.random.default_rng(0)
    img = np.clip(low_contrast_image() + rng.normal(0, 8, (240, 480)), 0, 255).astype(np.uint8)
    ex = CellExtractor(TrackingParams(n_features=500, n_levels=1, extractor="cells"))
    own = ex.extract(img)
    own_low = ex.last_stats["fast_low"]
    given = ex.extract(img, noise_sigma=image_noise_sigma(img))
    assert ex.last_stats["fast_low"] == own_low
    for a, b in zip((own.uv, own.octave, own.response, own.descriptors),
                    (given.uv, given.octave, given.response, given.descriptors)):
        np.testing.assert_array_equal(a, b)
    assert ex.fallback_for(img, None, noise_sigma=20.0) == (40, 20.0)
    ex.extract(img, noise_sigma=20.0)
    assert ex.last_stats["fast_low"] == 40 != own_low and ex.last_stats["noise_sigma"] == 20.0


def test_orientation_matches_cv2_orb_on_its_own_keypoints(kitti_pair):
    left, _, _ = kitti_pair
    orb = cv2.ORB_create(1000, 1.2, 1, 19, 0, 2, cv2.ORB_HARRIS_SCORE, 31, 20)
    kps = orb.detect(left, None)
    xy = np.array([k.pt for k in kps])
    assert np.all(xy == np.round(xy))  # level 0: integer pixels
    ours = ic_angles(left, xy[:, 0].astype(np.int64), xy[:, 1].astype(np.int64))
    theirs = np.array([k.angle for k in kps])
    diff = np.abs((ours - theirs + 180.0) % 360.0 - 180.0)
    assert np.percentile(diff, 99) < 3.0, np.percentile(diff, 99)


def test_orb_compute_keeps_the_given_angles(kitti_pair):
    """The descriptors depend on the angle we set: OpenCV does not recompute it."""
    left, _, _ = kitti_pair
    pts = np.array([[200.0, 150.0], [400.0, 200.0], [800.0, 180.0]], np.float32)
    orb = cv2.ORB_create(nlevels=1, edgeThreshold=19, patchSize=31)
    a = cv2.KeyPoint_convert(pts, 31.0)
    b = cv2.KeyPoint_convert(pts, 31.0)
    for k in a:
        k.angle = 0.0
    for k in b:
        k.angle = 90.0
    ka, da = orb.compute(left, a)
    kb, db = orb.compute(left, b)
    assert [k.angle for k in ka] == [0.0] * 3 and [k.angle for k in kb] == [90.0] * 3
    assert np.all(np.any(da != db, axis=1))


def test_harris_response_is_opencvs_up_to_scale(kitti_pair):
    left, _, _ = kitti_pair
    rng = np.random.default_rng(1)
    x, y = rng.integers(10, left.shape[1] - 10, 300), rng.integers(10, left.shape[0] - 10, 300)
    ref = cv2.cornerHarris(left.astype(np.float32), 7, 3, 0.04)[y, x]
    assert np.corrcoef(harris_responses(left, x, y), ref)[0, 1] > 0.999


def test_quadtree_select_spreads_to_the_quota():
    rng = np.random.default_rng(2)
    # a dense cluster with high scores and sparse points with low scores
    x = np.concatenate([rng.uniform(0, 50, 500), rng.uniform(0, 400, 100)])
    y = np.concatenate([rng.uniform(0, 50, 500), rng.uniform(0, 200, 100)])
    score = np.concatenate([rng.uniform(50, 100, 500), rng.uniform(0, 10, 100)])
    sel = quadtree_select(x, y, score, 0, 0, 400, 200, 60)
    assert len(sel) == 60 and len(np.unique(sel)) == 60
    assert (sel >= 500).sum() >= 30  # strongest-first would take the cluster only
    assert len(quadtree_select(x[:10], y[:10], score[:10], 0, 0, 400, 200, 60)) == 10


def test_best_ranks_marks_the_best_ranked_point_of_every_key():
    rng = np.random.default_rng(3)
    key = rng.integers(0, 50, 400) * 7            # sparse keys, most repeated
    rank = rng.permutation(400)
    ref = sorted(min(np.flatnonzero(key == k), key=lambda i: rank[i]) for k in np.unique(key))
    marked = _best_ranks(key, rank, int(key.max()) + 1)   # indexed by rank
    np.testing.assert_array_equal(np.sort(np.argsort(rank)[marked]), ref)


@pytest.mark.parametrize("ranking, share", [("harris2x", 0.95), ("fast", 0.8)])
def test_cell_descriptors_stereo_match_about_as_many_as_opencv(kitti_params, ranking, share):
    """Stereo matches on KITTI pairs 0, 20, 40 against cv2.ORB + grid bucketing. Measured:
    ``harris2x`` 98 % over the 11 pairs 0, 5, ..., 50 (7208 vs 7355; pair 0: 739 each), so the
    descriptors on our pyramid with our angles match as cv2.ORB's do; ``fast`` (the default, ORB-SLAM's
    choice) 85 % on these three (1731 vs 2039): it keeps FAST-strongest corners in low-texture road
    and sky cells where stereo is ambiguous -- and still tracks better (docs/notes/s6-cells.md)."""
    src = open_source("kitti")
    pc = replace(kitti_params, extractor="cells", cell_ranking=ranking)
    n_cells = n_cv = 0
    for i in (0, 20, 40):
        f = src.frame(i)
        cells = match_stereo(CellExtractor(pc).extract(f.left), CellExtractor(pc).extract(f.right), f.left, f.right,
                             src.calibration, pc)
        cv = match_stereo(OrbExtractor(kitti_params).extract(f.left), OrbExtractor(kitti_params).extract(f.right),
                          f.left, f.right, src.calibration, kitti_params)
        n_cells, n_cv = n_cells + int(cells.valid.sum()), n_cv + int(cv.valid.sum())
    assert n_cells >= share * n_cv, (n_cells, n_cv)


def test_disparity_offset_follows_the_extractor_that_found_the_keypoints(kitti_pair, kitti_params):
    left, right, calib = kitti_pair
    pc = replace(kitti_params, extractor="cells", disparity_offset_px=0.0, disparity_offset_cells_px=0.0)
    fl, fr = CellExtractor(pc).extract(left), CellExtractor(pc).extract(right)
    base = match_stereo(fl, fr, left, right, calib, pc)
    moved = match_stereo(fl, fr, left, right, calib, replace(pc, disparity_offset_cells_px=0.3))
    same = match_stereo(fl, fr, left, right, calib, replace(pc, disparity_offset_px=0.3))
    both = base.valid & moved.valid
    np.testing.assert_allclose(base.u_right[both] - moved.u_right[both], 0.3, atol=1e-4)
    np.testing.assert_array_equal(same.u_right, base.u_right)


def test_enhanced_frames_go_to_opencv_when_configured(kitti_pair, kitti_params):
    """The AFE rule passes a fallback threshold only on frames the enhancement changed."""
    left, _, _ = kitti_pair
    ex = CellExtractor(replace(kitti_params, extractor="cells", extractor_enhanced="opencv",
                               enhanced_cells_min_corners=0))
    assert ex.extract(left, 30, 15, 200).extractor == "opencv"
    # KITTI's rule (canopy.frontend.enhanced_extractor): a textured enhanced frame goes to cells
    assert CellExtractor(kitti_params).extract(left, 30, 15, 200).extractor == "cells"
    assert ex.extract(left, 30).extractor == "cells"  # the noise floor alone: still cells
    ex = CellExtractor(replace(kitti_params, extractor="cells", extractor_enhanced="cells"))
    assert ex.extract(left, 30, 15, 200).extractor == "cells"


@pytest.mark.parametrize("bad", [np.zeros((0, 0), np.uint8), np.zeros((50, 60, 3), np.uint8),
                                 np.zeros((50, 60), np.float32), None])
def test_bad_images_are_a_clear_error(bad):
    with pytest.raises(ValueError, match="CellExtractor.extract: image must be a non-empty 2-D uint8 grey image"):
        CellExtractor(TrackingParams(extractor="cells")).extract(bad)


def test_extractor_setting_is_validated_and_chooses_the_class():
    assert isinstance(make_extractor(TrackingParams(extractor="cells")), CellExtractor)
    assert isinstance(make_extractor(TrackingParams()), OrbExtractor)
    with pytest.raises(ConfigError, match="extractor"):
        TrackingParams(extractor="sift")
    with pytest.raises(ConfigError, match="extractor_enhanced"):
        TrackingParams(extractor_enhanced="cell")


def test_descriptors_equal_cv2_orbs_on_its_own_keypoints(kitti_pair, kitti_params):
    """Our pyramid is cv2.ORB's (bit-exact resize of the previous level) and compute keeps the
    given angle: on cv2.ORB's level-0 and level-1 keypoints the descriptors are identical."""
    left, _, _ = kitti_pair
    ex = CellExtractor(replace(kitti_params, extractor="cells"))
    orb = cv2.ORB_create(2000, 1.2, 8, 19, 0, 2, cv2.ORB_HARRIS_SCORE, 31, 20)
    kps, desc = orb.detectAndCompute(left, None)
    pyr = ex.pyramid(left)
    for lvl in (0, 1):
        idx = [i for i, k in enumerate(kps) if k.octave == lvl][:200]
        s = 1.2 ** lvl
        ours = [cv2.KeyPoint(kps[i].pt[0] / s, kps[i].pt[1] / s, 31, kps[i].angle, 1.0, 0, i) for i in idx]
        out, d = ex._orb.compute(pyr[lvl], ours)
        assert [k.class_id for k in out] == idx
        np.testing.assert_array_equal(d, desc[idx])


def fallback_by_row_spans(ex: CellExtractor, img: np.ndarray, high: int, low: int):
    """Written-out reference for detect_level: FAST at ``high`` over the region, then at ``low`` one
    call per cell row on a view from its first to its last empty cell (3 px border), corners kept in
    the empty cells. Returns (x, y, score) and the number of rows whose span holds a non-empty cell."""
    h, w = img.shape
    b, cs = ex.border, ex.params.cell_size
    x0, y0, x1, y1 = b, b, w - b, h - b
    ncol, nrow = max(1, (x1 - x0) // cs), max(1, (y1 - y0) // cs)
    cw, ch = int(np.ceil((x1 - x0) / ncol)), int(np.ceil((y1 - y0) / nrow))

    def fast(t, ya, yb, xa, xb):
        kps = cv2.FastFeatureDetector_create(t, True).detect(img[ya - 3:yb + 3, xa - 3:xb + 3])
        pts = np.array([k.pt for k in kps], np.int64).reshape(-1, 2) + (xa - 3, ya - 3)
        return pts, np.array([k.response for k in kps], np.float32)

    pts, score = fast(high, y0, y1, x0, x1)
    cell = np.minimum((pts[:, 1] - y0) // ch, nrow - 1) * ncol + np.minimum((pts[:, 0] - x0) // cw, ncol - 1)
    empty = (np.bincount(cell, minlength=nrow * ncol) == 0).reshape(nrow, ncol)
    out_p, out_s, gapped = [pts], [score], 0
    for r in range(nrow):
        cols = np.flatnonzero(empty[r])
        if len(cols) == 0:
            continue
        gapped += int(cols[-1] - cols[0] + 1 > len(cols))
        ya, yb = y0 + r * ch, (y0 + (r + 1) * ch if r < nrow - 1 else y1)
        xa, xb = x0 + cols[0] * cw, (x0 + (cols[-1] + 1) * cw if cols[-1] < ncol - 1 else x1)
        q, sq = fast(low, ya, yb, xa, xb)
        ok = empty[r, np.minimum((q[:, 0] - x0) // cw, ncol - 1)]
        out_p.append(q[ok])
        out_s.append(sq[ok])
    p = np.concatenate(out_p)
    return p[:, 0], p[:, 1], np.concatenate(out_s), gapped


def test_fallback_on_runs_of_empty_cells_equals_fast_over_row_spans(kitti_pair, kitti_params):
    """FAST runs only on runs of adjacent empty cells (1 px into the non-empty neighbours): the same
    corners, scores and order as one call per cell row spanning its empty cells."""
    left, right, _ = kitti_pair
    rng = np.random.default_rng(1)
    noisy = np.clip(low_contrast_image() + rng.normal(0, 3, (240, 480)), 0, 255).astype(np.uint8)
    ex = CellExtractor(replace(kitti_params, extractor="cells"))
    gapped_total = 0
    for img in (left, right, noisy):
        for level in ex.pyramid(img):
            x, y, score, _ = ex.detect_level(level, 20, 7)
            rx, ry, rscore, gapped = fallback_by_row_spans(ex, level, 20, 7)
            gapped_total += gapped
            np.testing.assert_array_equal(x, rx)
            np.testing.assert_array_equal(y, ry)
            np.testing.assert_array_equal(score, rscore)
    assert gapped_total > 20  # many rows had non-empty cells between their empty ones


def test_keypoints_opencv_drops_at_the_border_leave_the_rest_aligned(kitti_pair, kitti_params):
    """When cv2.ORB.compute drops keypoints (here: its border is wider than the extractor's), every
    remaining keypoint keeps its own descriptor and response."""
    left, _, _ = kitti_pair
    p = replace(kitti_params, extractor="cells", edge_threshold=40)
    ex = CellExtractor(p)
    ex.border = 19                                # detect closer to the edge than ORB describes
    f = ex.extract(left)
    lvl0 = f.octave == 0
    x, y = f.uv[lvl0, 0].astype(np.int64), f.uv[lvl0, 1].astype(np.int64)
    h, w = left.shape
    assert lvl0.sum() < ex.quotas[0]              # some were dropped ...
    assert np.all((x >= 40) & (x < w - 40) & (y >= 40) & (y < h - 40))  # ... those inside ORB's border
    kps = cv2.KeyPoint_convert(np.column_stack([x, y]).astype(np.float32), 31.0)
    for k, a in zip(kps, ic_angles(left, x, y).tolist()):
        k.angle = a
    orb = cv2.ORB_create(nlevels=1, edgeThreshold=40, patchSize=31)
    _, d = orb.compute(left, kps)
    np.testing.assert_array_equal(f.descriptors[lvl0], d)
    np.testing.assert_array_equal(f.response[lvl0], harris_responses(left, x, y))


def test_without_responses_the_features_are_the_same_and_responses_zero(kitti_pair, kitti_params):
    """The tracker's extractors skip the Harris responses (nothing downstream reads them): the same
    keypoints, octaves and descriptors, responses all zero; the other rankings still compute them."""
    left, right, _ = kitti_pair
    for img in (left, right):
        full = CellExtractor(kitti_params).extract(img)
        lean = CellExtractor(kitti_params, responses=False).extract(img)
        for a, b in zip((full.uv, full.octave, full.descriptors), (lean.uv, lean.octave, lean.descriptors)):
            np.testing.assert_array_equal(a, b)
        assert np.all(lean.response == 0) and np.any(full.response != 0)
    harris = replace(kitti_params, cell_ranking="harris")
    np.testing.assert_array_equal(CellExtractor(harris, responses=False).extract(left).response,
                                  CellExtractor(harris).extract(left).response)
    assert isinstance(make_extractor(kitti_params, responses=False), CellExtractor)


def test_descending_key_sorts_as_the_negated_scores():
    """FAST scores (integers stored as float32, many ties) sort by an int16 key in the same
    stable order as -score; other scores (Harris, fractions, out of int16 range) keep -score."""
    rng = np.random.default_rng(5)
    fast = rng.integers(7, 90, 3000).astype(np.float32)
    key = _descending_key(fast)
    assert key.dtype == np.int16
    np.testing.assert_array_equal(np.argsort(key, kind="stable"), np.argsort(-fast, kind="stable"))
    for other in (fast + 0.5, fast * 1e3, rng.uniform(0, 1, 50).astype(np.float32)):
        assert _descending_key(other).dtype.kind == "f"
        np.testing.assert_array_equal(np.argsort(_descending_key(other), kind="stable"),
                                      np.argsort(-other, kind="stable"))
    assert len(_descending_key(np.zeros(0, np.float32))) == 0
