"""The projection search (``match_in_window``) against a plain dense reference (issue 8, speed;
s19-mapsearch): the pairs in cell order with per-thread scratch buffers must give the matches of
the definition written out over the full query x reference product, including which of several
equally distant references wins (the earlier one in the grid's order: by cell, then index)."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from canopy.frontend import matching
from canopy.frontend.matching import as_words, match_in_window


def _grid_rank(q_uv, r_uv, cells_per_ref):
    """Each reference's rank in a query's pair list: by its cell key on the grid of its scale
    (grids one after the other in the order of the scales), then by index."""
    lo = np.minimum(q_uv.min(axis=0), r_uv.min(axis=0))
    hi = np.maximum(q_uv.max(axis=0), r_uv.max(axis=0))
    cells, group = np.unique(cells_per_ref, return_inverse=True)
    group = group.reshape(-1)
    n_cols = ((hi[0] - lo[0]) // cells).astype(np.int64) + 3
    n_rows = ((hi[1] - lo[1]) // cells).astype(np.int64) + 3
    offset = np.concatenate([[0], np.cumsum(n_cols * n_rows)[:-1]])
    col = ((r_uv[:, 0] - lo[0]) // cells[group]).astype(np.int64)
    row = ((r_uv[:, 1] - lo[1]) // cells[group]).astype(np.int64)
    key = offset[group] + row * n_cols[group] + col
    rank = np.empty(len(key), np.int64)
    rank[np.lexsort((np.arange(len(key)), key))] = np.arange(len(key))
    return rank


def plain_match_in_window(q_uv, q_desc, q_radius, r_uv, r_desc, max_hamming, ratio, q_mask=None, r_scale=None,
                          r_level=None):
    """The definition over every (query, reference) pair: inside the circle, best and second-best
    Hamming distance (ties to the lower grid rank), Lowe's ratio (only between candidates on one
    level with ``r_level``), each reference kept for its closest query (ties to the lower query)."""
    n_q, n_r = len(q_uv), len(r_uv)
    sel = np.ones(n_q, bool) if q_mask is None else np.asarray(q_mask, bool)
    if n_q == 0 or n_r == 0 or not sel.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    scale = np.ones(n_r) if r_scale is None else r_scale
    rmax = float(np.max(q_radius[sel]))
    rank = _grid_rank(q_uv[sel], r_uv, np.maximum(rmax * scale, 1.0))
    q64, r64 = q_uv.astype(np.float64), r_uv.astype(np.float64)
    d2 = (q64[:, None, 0] - r64[None, :, 0]) ** 2 + (q64[:, None, 1] - r64[None, :, 1]) ** 2
    rad = q_radius[:, None] * scale[None, :]
    inside = (d2 <= rad * rad) & sel[:, None]
    ham = np.unpackbits(q_desc[:, None, :] ^ r_desc[None, :, :], axis=2).sum(axis=2).astype(np.int64)
    big = np.iinfo(np.int64).max
    key = np.where(inside, ham * n_r + rank[None, :], big)
    best_key = key.min(axis=1)
    best = np.where(best_key < big, key.argmin(axis=1), -1)
    key[np.arange(n_q), np.maximum(best, 0)] = big
    sec_key = key.min(axis=1)
    second = np.where(sec_key < big, key.argmin(axis=1), -1)
    best_d = np.where(best >= 0, best_key // n_r, 1 << 20)
    second_d = np.where(second >= 0, sec_key // n_r, 1 << 20)
    ambiguous = best_d >= ratio * second_d
    if r_level is not None:
        ambiguous &= (second >= 0) & (r_level[np.maximum(second, 0)] == r_level[np.maximum(best, 0)])
    q = np.flatnonzero((best >= 0) & (best_d <= max_hamming) & ~ambiguous)
    r, d = best[q], best_d[q]
    keep = np.zeros(len(q), bool)
    for ref in np.unique(r):          # a handful of matches: the closest query, ties to the lower
        idx = np.flatnonzero(r == ref)
        keep[idx[np.argmin(d[idx])]] = True
    return q[keep].astype(np.int64), r[keep].astype(np.int64), d[keep].astype(np.int64)


def _scene(seed, n_q=300, n_r=500, n_levels=8, size=(300.0, 120.0), float32_refs=True):
    """Queries near references and spread out; descriptors from a few patterns, so equal
    distances are common and the tie rule decides."""
    rng = np.random.default_rng(seed)
    patterns = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    r_desc = patterns[rng.integers(0, 5, n_r)].copy()
    r_desc[np.arange(n_r), rng.integers(0, 32, n_r)] ^= np.uint8(1 << rng.integers(0, 8))
    q_desc = patterns[rng.integers(0, 5, n_q)].copy()
    r_uv = rng.uniform(0, size, (n_r, 2))
    if float32_refs:
        r_uv = r_uv.astype(np.float32)          # keypoints are float32, projections float64
    half = n_q // 2
    q_uv = np.concatenate([r_uv[:half] + rng.normal(0, 2.0, (half, 2)), rng.uniform(-5, [size[0] + 5, size[1] + 5],
                                                                                  (n_q - half, 2))])
    level = rng.integers(0, n_levels, n_r).astype(np.int32)
    return rng, q_uv, q_desc, r_uv, r_desc, level, 1.2 ** level


def _assert_same(got, want):
    for g, w in zip(got, want):
        assert g.dtype == np.int64
        np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("radius", [4.0, 10.0, 0.6])
def test_motion_search_equals_plain_reference(seed, radius):
    """One radius, no scales (the motion-model search), with a mask hiding a third of the queries."""
    rng, q_uv, q_desc, r_uv, r_desc, _, _ = _scene(seed)
    mask = rng.random(len(q_uv)) < 0.67
    args = (q_uv, as_words(q_desc), np.full(len(q_uv), radius), r_uv, as_words(r_desc), 40, 0.9)
    got = match_in_window(*args, q_mask=mask)
    want = plain_match_in_window(q_uv, q_desc, np.full(len(q_uv), radius), r_uv, r_desc, 40, 0.9, q_mask=mask)
    assert len(want[0]) > (0 if radius < 1 else 20)        # radius < 1: cells of 1 px (clamped)
    _assert_same(got, want)


@pytest.mark.parametrize("seed,n_levels,bands", [(0, 8, 3), (1, 8, 3), (2, 3, 3), (3, 2, 3), (4, 8, 1)])
def test_scaled_search_equals_plain_reference(seed, n_levels, bands, monkeypatch):
    """The local-map search: windows scaled per reference level, the ratio test within a level;
    more levels than grids (tie ranks from the per-scale grids) and as many (no ranks needed)."""
    monkeypatch.setattr(matching, "SCALE_BANDS", bands)
    _, q_uv, q_desc, r_uv, r_desc, level, scale = _scene(seed, n_levels=n_levels)
    args = (q_uv, as_words(q_desc), np.full(len(q_uv), 4.0), r_uv, as_words(r_desc), 40, 0.9)
    got = match_in_window(*args, r_scale=scale, r_level=level)
    want = plain_match_in_window(q_uv, q_desc, np.full(len(q_uv), 4.0), r_uv, r_desc, 40, 0.9, r_scale=scale,
                                 r_level=level)
    assert len(want[0]) > 20
    _assert_same(got, want)


@pytest.mark.parametrize("scaled", [False, True])
def test_per_query_radii_equal_plain_reference(scaled):
    """Radii that differ between queries take the general circle test (not the one-radius path)."""
    rng, q_uv, q_desc, r_uv, r_desc, level, scale = _scene(7, float32_refs=False)
    radius = rng.uniform(2.0, 9.0, len(q_uv))
    kw = dict(r_scale=scale, r_level=level) if scaled else {}
    got = match_in_window(q_uv, as_words(q_desc), radius, r_uv, as_words(r_desc), 40, 0.9, **kw)
    want = plain_match_in_window(q_uv, q_desc, radius, r_uv, r_desc, 40, 0.9, **kw)
    assert len(want[0]) > 20
    _assert_same(got, want)


def test_scratch_reuse_across_sizes_and_empty_searches():
    """Calls of growing and shrinking size reuse the buffers (longer than needed) and stay exact;
    searches without pairs, queries or references return empty int64 arrays."""
    for seed, n_q, n_r in [(10, 400, 800), (11, 30, 40), (12, 600, 900), (13, 5, 3)]:
        _, q_uv, q_desc, r_uv, r_desc, level, scale = _scene(seed, n_q=n_q, n_r=n_r)
        args = (q_uv, as_words(q_desc), np.full(n_q, 6.0), r_uv, as_words(r_desc), 60, 0.95)
        _assert_same(match_in_window(*args), plain_match_in_window(q_uv, q_desc, np.full(n_q, 6.0), r_uv, r_desc,
                                                                   60, 0.95))
        _assert_same(match_in_window(*args, r_scale=scale, r_level=level),
                     plain_match_in_window(q_uv, q_desc, np.full(n_q, 6.0), r_uv, r_desc, 60, 0.95, r_scale=scale,
                                           r_level=level))
    _, q_uv, q_desc, r_uv, r_desc, _, _ = _scene(14)
    far = q_uv + 1000.0                                                      # no pairs at all
    for out in (match_in_window(far, as_words(q_desc), np.full(len(q_uv), 4.0), r_uv, as_words(r_desc), 40, 0.9),
                match_in_window(q_uv, as_words(q_desc), np.full(len(q_uv), 4.0), r_uv, as_words(r_desc), 40, 0.9,
                                q_mask=np.zeros(len(q_uv), bool)),
                match_in_window(q_uv, as_words(q_desc), np.full(len(q_uv), 4.0), r_uv[:0], as_words(r_desc[:0]), 40,
                                0.9)):
        assert [len(a) for a in out] == [0, 0, 0] and all(a.dtype == np.int64 for a in out)


def test_results_do_not_alias_the_scratch_buffers():
    """A second search must not change the first one's returned arrays."""
    _, q_uv, q_desc, r_uv, r_desc, level, scale = _scene(20)
    args = (q_uv, as_words(q_desc), np.full(len(q_uv), 8.0), r_uv, as_words(r_desc), 60, 0.95)
    first = match_in_window(*args)
    kept = [a.copy() for a in first]
    match_in_window(q_uv[::-1].copy(), *args[1:], r_scale=scale, r_level=level)
    _assert_same(first, kept)


def test_threads_searching_at_once_get_their_own_results():
    """The stereo worker and the tracking thread match at the same time: per-thread buffers."""
    cases = []
    for seed in range(4):
        _, q_uv, q_desc, r_uv, r_desc, level, scale = _scene(30 + seed, n_q=500, n_r=900)
        args = (q_uv, as_words(q_desc), np.full(len(q_uv), 8.0), r_uv, as_words(r_desc), 60, 0.95)
        cases.append((args, dict(r_scale=scale, r_level=level) if seed % 2 else {}))
    want = [match_in_window(*a, **k) for a, k in cases]
    got = [[] for _ in cases]

    def run(i):
        for _ in range(15):
            got[i].append(match_in_window(*cases[i][0], **cases[i][1]))

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(cases))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i, runs in enumerate(got):
        assert len(runs) == 15
        for out in runs:
            _assert_same(out, want[i])


def test_pairs_exactly_on_the_circle_are_inside():
    """Integer coordinates and radius 5 (3-4-5 triangles): pairs at exactly the radius count."""
    rng = np.random.default_rng(40)
    r_uv = rng.integers(0, 60, (400, 2)).astype(np.float64)
    q_uv = r_uv[:200] + np.array([3.0, 4.0])
    desc = rng.integers(0, 256, (400, 32), dtype=np.uint8)
    q_desc = desc[:200].copy()
    args = (q_uv, as_words(q_desc), np.full(200, 5.0), r_uv, as_words(desc), 40, 0.9)
    got = match_in_window(*args)
    want = plain_match_in_window(q_uv, q_desc, np.full(200, 5.0), r_uv, desc, 40, 0.9)
    on_circle = ((q_uv[want[0]] - r_uv[want[1]]) ** 2).sum(axis=1) == 25.0
    assert on_circle.sum() > 20
    _assert_same(got, want)


def test_searches_beyond_the_kept_scratch_size_are_exact(monkeypatch):
    """Searches with more pairs than the per-thread buffers keep get fresh arrays, same matches."""
    monkeypatch.setattr(matching._Scratch, "MAX_KEPT", 500)
    for scaled in (False, True):
        _, q_uv, q_desc, r_uv, r_desc, level, scale = _scene(50)
        kw = dict(r_scale=scale, r_level=level) if scaled else {}
        args = (q_uv, as_words(q_desc), np.full(len(q_uv), 8.0), r_uv, as_words(r_desc), 60, 0.95)
        _assert_same(match_in_window(*args, **kw),
                     plain_match_in_window(q_uv, q_desc, np.full(len(q_uv), 8.0), r_uv, r_desc, 60, 0.95, **kw))


@pytest.mark.parametrize("size", [(300.0, 120.0), (3000.0, 1000.0)])
def test_grids_below_and_above_2_16_cells(size):
    """The references' cell order by a 16-bit radix sort (small grids) or int64 (large ones, here
    ~2 * 10^5 cells of 4 px): both give the dense reference's matches."""
    _, q_uv, q_desc, r_uv, r_desc, level, scale = _scene(60, n_q=400, n_r=1500, size=size)
    for kw in ({}, dict(r_scale=scale, r_level=level)):
        args = (q_uv, as_words(q_desc), np.full(len(q_uv), 4.0), r_uv, as_words(r_desc), 60, 0.95)
        _assert_same(match_in_window(*args, **kw),
                     plain_match_in_window(q_uv, q_desc, np.full(len(q_uv), 4.0), r_uv, r_desc, 60, 0.95, **kw))
    keys = np.random.default_rng(61).integers(0, 70000, 3000)
    for n_keys in (70000, 1 << 16):
        k = keys % n_keys
        np.testing.assert_array_equal(matching._stable_order(k, n_keys), np.argsort(k, kind="stable"))
