"""The cell extractor's all-levels-at-once steps (canopy.frontend.cell_levels) give exactly what the
per-level code gave: the same keypoints, octaves, responses and descriptors in the same order."""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from canopy.config import load_run_config
from canopy.degrade import NOISE_LEVELS, darken
from canopy.frontend.cell_extractor import CellExtractor, harris_responses, ic_angles, quadtree_select
from canopy.frontend.cell_levels import KeyPointPool, ic_angles_levels
from canopy.frontend.features import Features
from canopy.sources import open_source


def reference_extract(ex: CellExtractor, img: np.ndarray, responses: bool) -> Features:
    """CellExtractor.extract written out level by level (no enhanced frames): FAST corners, quadtree
    (and Harris ranking), intensity-centroid angles, new cv2.KeyPoints, ORB.compute on that level."""
    p = ex.params
    low, _ = ex.fallback_for(img, None)
    uv, octave, response, desc = [], [], [], []
    for lvl, level in enumerate(ex.pyramid(img)):
        quota = int(ex.quotas[lvl])
        if quota <= 0:
            continue
        x, y, score, region = ex.detect_level(level, p.fast_threshold, low)
        if len(x) == 0:
            continue
        xf, yf = x.astype(np.float64), y.astype(np.float64)
        if p.cell_ranking == "fast":
            sel = quadtree_select(xf, yf, score, *region, quota)
            h = harris_responses(level, x[sel], y[sel]) if responses else np.zeros(len(sel), np.float32)
        elif p.cell_ranking == "harris2x":
            sel = quadtree_select(xf, yf, score, *region, 2 * quota)
            h = harris_responses(level, x[sel], y[sel])
            keep = np.sort(np.argsort(-h, kind="stable")[:quota])
            sel, h = sel[keep], h[keep]
        else:
            h = harris_responses(level, x, y)
            sel = quadtree_select(xf, yf, h, *region, quota)
            h = h[sel]
        x, y = x[sel], y[sel]
        angles = ic_angles(level, x, y)
        kps = [cv2.KeyPoint(float(a), float(b), float(p.patch_size), float(t)) for a, b, t in zip(x, y, angles)]
        kps, d = ex._orb.compute(level, kps)
        if d is None or len(kps) == 0:
            continue
        assert len(kps) == len(x)  # keypoints >= 19 px inside: OpenCV drops none
        s = float(ex.scale_factors[lvl])
        uv.append(np.column_stack([x, y]).astype(np.float32) * s)
        octave.append(np.full(len(x), lvl, np.int32))
        response.append(h)
        desc.append(d)
    return Features(np.concatenate(uv), np.concatenate(octave), np.concatenate(response), np.concatenate(desc),
                    extractor="cells")


def assert_same(a: Features, b: Features) -> None:
    for field in ("uv", "octave", "response", "descriptors"):
        x, y = getattr(a, field), getattr(b, field)
        assert x.dtype == y.dtype, field
        np.testing.assert_array_equal(x, y, err_msg=field)
    assert a.extractor == b.extractor


def frames(dataset: str, idx: tuple[int, ...]) -> list[np.ndarray]:
    src = open_source(dataset, max_frames=max(idx) + 1)
    out = []
    for i in idx:
        f = src.frame(i)
        out += [f.left, f.right]
    return out


@pytest.fixture(scope="module")
def images() -> dict[str, list[np.ndarray]]:
    kitti = frames("kitti", (0, 25, 50))
    full_well, read_noise = NOISE_LEVELS["high"]
    # dark, noisy frames (the grid's noisy sensor): at 30 % light the fallback threshold is raised by
    # the noise floor (2 x sigma 4.3 -> 9), at 6 % most cells find nothing at 20 and take the fallback
    dark = [darken(kitti[0], g, full_well, read_noise, rng=3) for g in (0.3, 0.06)]
    return {"kitti": kitti, "euroc": frames("euroc", (0, 40, 90)), "dark": dark}


@pytest.mark.parametrize("dataset", ["kitti", "euroc"])
@pytest.mark.parametrize("responses", [False, True])
def test_extract_equals_the_per_level_reference(images, dataset, responses):
    """KITTI and EuRoC frames (left and right) with each dataset's tracking settings, and KITTI's on a
    dark noisy frame; one extractor for all images (the keypoint pool is reused), as the tracker's."""
    # EuRoC tracks with cv2.ORB (extractor: opencv): its frames with the cells extractor at its settings
    params = replace(load_run_config(dataset).tracking, extractor="cells")
    assert params.cell_ranking == "fast"
    ex = CellExtractor(params, responses=responses)
    imgs = images[dataset] + (images["dark"] if dataset == "kitti" else [])
    for img in imgs:
        ours = ex.extract(img)
        assert len(ours) > 0.25 * params.n_features
        assert_same(ours, reference_extract(ex, img, responses))


def test_the_dark_frame_exercises_the_fallback_and_its_noise_floor(images):
    """The dark frames are what the test above needs them for: on one the noise floor raises the
    fallback threshold, on the other most corners are the fallback's."""
    params = load_run_config("kitti").tracking
    ex = CellExtractor(params, responses=False)
    ex.extract(images["dark"][0])
    assert ex.last_stats["fast_low"] > params.fast_fallback_threshold
    very_dark = images["dark"][1]
    x, y, _, _ = ex.detect_level(very_dark, params.fast_threshold, params.fast_threshold)  # no fallback
    assert len(ex.extract(very_dark)) > 2 * len(x)


def test_angles_of_all_levels_equal_the_per_level_ones(images):
    ex = CellExtractor(load_run_config("kitti").tracking, responses=False)
    img = images["kitti"][0]
    levels, xs, ys = [], [], []
    for level in ex.pyramid(img):
        x, y, _, _ = ex.detect_level(level, 20, 7)
        levels.append(level)
        xs.append(x)
        ys.append(y)
    xs[3], ys[3] = xs[3][:0], ys[3][:0]  # a level without corners
    starts = np.concatenate([[0], np.cumsum([len(x) for x in xs])])
    ours = ic_angles_levels(levels, np.concatenate(xs), np.concatenate(ys), starts)
    ref = np.concatenate([ic_angles(lv, x, y) for lv, x, y in zip(levels, xs, ys)])
    assert ours.dtype == np.float32
    np.testing.assert_array_equal(ours, ref)
    assert len(ic_angles_levels(levels, xs[3], ys[3], np.zeros(len(levels) + 1, np.int64))) == 0


def test_pooled_keypoints_are_fresh_keypoints():
    pool = KeyPointPool(31)
    rng = np.random.default_rng(0)
    for n in (5, 40, 12):  # grows, then reuses part of the pool
        x, y = rng.integers(0, 500, n), rng.integers(0, 300, n)
        ang = (rng.random(n) * 360).astype(np.float32)
        kps = pool.keypoints(x, y, ang)
        assert len(kps) == n
        for k, a, b, t in zip(kps, x, y, ang):
            ref = cv2.KeyPoint(float(a), float(b), 31.0, float(t))
            assert (k.pt, k.size, k.angle, k.octave, k.response) == (ref.pt, ref.size, ref.angle, ref.octave, ref.response)


@pytest.mark.parametrize("ranking", ["harris2x", "harris"])
def test_the_harris_rankings_equal_the_per_level_reference(images, ranking):
    params = replace(load_run_config("kitti").tracking, cell_ranking=ranking)
    ex = CellExtractor(params)
    for img in images["kitti"][:2]:
        assert_same(ex.extract(img), reference_extract(ex, img, True))


def reference_quadtree(x, y, score, x0, y0, width, height, quota) -> np.ndarray:
    """quadtree_select written out with Python sets and dicts: regular 2^d subdivisions of ORB-SLAM's
    ~square root nodes, the first depth (from log4(quota / roots)) whose occupied nodes reach the
    quota, the best (score, then input order) per node; over quota: every parent node's best, then
    the other winners by rank up to the quota."""
    n = len(x)
    if n <= quota:
        return np.arange(n)
    if quota <= 0:
        return np.zeros(0, np.int64)
    n_root = max(1, int(round(width / height)))
    rw = width / n_root
    rank = {int(i): r for r, i in enumerate(sorted(range(n), key=lambda i: (-float(score[i]), i)))}

    def nodes(d):
        k = 2 ** d
        return [(int(np.floor((float(y[i]) - y0) / height * k)), int(np.floor((float(x[i]) - x0) / rw * k)))
                for i in range(n)]

    def best(keys):
        out = {}
        for i, key in enumerate(keys):
            if key not in out or rank[i] < rank[out[key]]:
                out[key] = i
        return set(out.values())

    depth = max(0, int(np.floor(np.log(quota / n_root) / np.log(4.0))))
    while not (len(set(nodes(depth))) >= quota or rw / 2 ** depth < 1.0):
        depth += 1
    winners = best(nodes(depth))
    if len(winners) <= quota:
        return np.array(sorted(winners), np.int64)
    parents = best(nodes(depth - 1)) if depth > 0 else set()
    rest = sorted(winners - parents, key=rank.get)[: quota - len(parents)]
    return np.array(sorted(parents | set(rest)), np.int64)


def test_quadtree_select_equals_a_written_out_reference():
    """Random points with many tied scores (FAST's are integers), float and int16 scores, int and
    float coordinates, quotas from 0 to above the point count."""
    rng = np.random.default_rng(5)
    for _ in range(60):
        n = int(rng.integers(1, 700))
        w, h = int(rng.integers(20, 1300)), int(rng.integers(20, 400))
        x0, y0 = int(rng.integers(0, 30)), int(rng.integers(0, 30))
        x, y = x0 + rng.integers(0, w, n), y0 + rng.integers(0, h, n)
        score = rng.integers(0, int(rng.integers(1, 30)), n)
        quota = int(rng.integers(0, n + 20))
        ref = reference_quadtree(x, y, score, x0, y0, w, h, quota)
        for xs, ys, sc in ((x, y, score.astype(np.int16)), (x.astype(np.float64), y.astype(np.float64),
                                                               score.astype(np.float32))):
            np.testing.assert_array_equal(quadtree_select(xs, ys, sc, x0, y0, w, h, quota), ref)
