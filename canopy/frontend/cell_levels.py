"""The cell extractor's per-level steps done for all pyramid levels at once (issue 8, speed).

``CellExtractor`` spreads each level's FAST corners with ``quadtree_select`` (ORB-SLAM's
``DistributeOctTree``), orients them with ``ic_angles`` (Rosin's intensity centroid) and hands them
to ``cv2.ORB.compute`` as ``cv2.KeyPoint`` objects. Done level by level that is ~60 + ~15 numpy calls
per level whose fixed cost (~2 us each) outweighs the work on the small levels: a KITTI image's
level 7 has 370 candidates, level 0 4300, and the quadtree took 100 vs 290 us. Here the same
arithmetic runs on all levels' points in one pass each; the outputs are equal to the per-level
functions' (tests/test_cell_levels.py checks them against those and the extractor against a
written-out per-level reference).

Levels are contiguous segments of the point arrays: level l holds points ``starts[l]:starts[l+1]``.
"""
from __future__ import annotations

import cv2
import numpy as np

HALF_PATCH = 15            # ORB's orientation patch radius (HALF_PATCH_SIZE)


def _circle_offsets() -> tuple[np.ndarray, np.ndarray]:
    """(u, v) offsets of ORB's circular orientation patch (its ``umax`` table, radius 15)."""
    vmax = int(np.floor(HALF_PATCH * np.sqrt(2.0) / 2 + 1))
    vmin = int(np.ceil(HALF_PATCH * np.sqrt(2.0) / 2))
    umax = np.zeros(HALF_PATCH + 1, np.int64)
    for v in range(vmax + 1):
        umax[v] = int(np.round(np.sqrt(HALF_PATCH ** 2 - v * v)))
    v0 = 0
    for v in range(HALF_PATCH, vmin - 1, -1):  # symmetric about the diagonal, as OpenCV / ORB-SLAM
        while umax[v0] == umax[v0 + 1]:
            v0 += 1
        umax[v] = v0
        v0 += 1
    us, vs = [], []
    for v in range(-HALF_PATCH, HALF_PATCH + 1):
        u = np.arange(-umax[abs(v)], umax[abs(v)] + 1)
        us.append(u)
        vs.append(np.full(len(u), v))
    return np.concatenate(us), np.concatenate(vs)


CIRCLE_U, CIRCLE_V = _circle_offsets()
# u (resp. v) inside the circle, 0 outside: the intensity centroid's two moments as one product
MASK_UV = np.zeros((2, 2 * HALF_PATCH + 1, 2 * HALF_PATCH + 1), np.float32)
MASK_UV[0, CIRCLE_V + HALF_PATCH, CIRCLE_U + HALF_PATCH] = CIRCLE_U
MASK_UV[1, CIRCLE_V + HALF_PATCH, CIRCLE_U + HALF_PATCH] = CIRCLE_V


def _segments(starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(counts per level, level of every point) of contiguous segments ``starts`` (length levels + 1)."""
    counts = np.diff(starts)
    return counts, np.repeat(np.arange(len(counts)), counts)


def quadtree_select_levels(x: np.ndarray, y: np.ndarray, score: np.ndarray, starts, regions, quotas) -> np.ndarray:
    """``quadtree_select`` on every level: the concatenation over levels l of
    ``starts[l] + quadtree_select(x_l, y_l, score_l, *regions[l], quotas[l])`` (sorted indices).

    ``regions[l]`` = (x0, y0, width, height) of level l's detection region; every point must lie in
    its level's region (x >= x0, y >= y0: the extractor's always do). ``score``: FAST scores
    (integers 0..255 as float32), as ``quadtree_select`` ranks them (best first, ties in input order).

    How the per-level loop maps to arrays (ORB-SLAM's nodes are the cells of a regular 2^d
    subdivision of its ~square root nodes, cell_extractor.quadtree_select):
    * node coordinates at every depth from one integer pair per point: floor(r 2^d) =
      floor(r 2^D) >> (D - d) for D >= d (r 2^D is exact in floating point: a power-of-two scale);
    * each level's depth is the first from its start depth at which its occupied nodes reach its
      quota (or nodes get narrower than a pixel): counted for all levels per depth by marking
      (level offset + node key) in one table;
    * best point per node = smallest rank, one ``np.minimum.at`` over all levels' keys, with a
      rank that orders by (level, score descending, index): within a level it is the level's rank.
    """
    starts = np.asarray(starts, np.int64)
    counts, lvl = _segments(starts)
    n_lv = len(counts)
    n = int(starts[-1])
    quotas = [int(q) for q in quotas]
    take_all = [int(c) <= q for c, q in zip(counts, quotas)]          # quadtree_select: n <= quota
    tree = [not a and q > 0 for a, q in zip(take_all, quotas)]       # else quota <= 0: none
    parts = [np.arange(starts[i], starts[i + 1]) for i in range(n_lv) if take_all[i] and counts[i] > 0]
    if not any(tree):
        return np.concatenate(parts) if parts else np.zeros(0, np.int64)
    # per-level constants exactly as quadtree_select computes them (Python floats)
    n_root = [max(1, int(round(r[2] / r[3]))) if t else 1 for r, t in zip(regions, tree)]
    rw = [r[2] / nr for r, nr in zip(regions, n_root)]
    depth0 = [max(0, int(np.floor(np.log(q / nr) / np.log(4.0)))) if t else 0
              for q, nr, t in zip(quotas, n_root, tree)]
    depth_cap = []                                                     # first depth with rw / 2^d < 1
    for w in rw:
        d = 0
        while not w / 2 ** d < 1.0:
            d += 1
        depth_cap.append(d)
    last = [max(c, d0) for c, d0 in zip(depth_cap, depth0)]           # the loop stops there at the latest
    D = max(last[i] for i in range(n_lv) if tree[i])
    # points of the quadtree levels only
    sel = np.flatnonzero(np.repeat(np.asarray(tree), counts))
    L = lvl[sel]
    f64 = np.float64
    x0 = np.array([r[0] for r in regions], f64)[L]
    y0 = np.array([r[1] for r in regions], f64)[L]
    rx = (np.asarray(x, f64)[sel] - x0) / np.asarray(rw, f64)[L]
    ry = (np.asarray(y, f64)[sel] - y0) / np.array([float(r[3]) for r in regions], f64)[L]
    if len(rx) and (rx.min() < 0 or ry.min() < 0):
        raise ValueError("quadtree_select_levels: points must lie in their level's region (x >= x0, y >= y0)")
    ixD = (rx * 2.0 ** D).astype(np.int64)      # truncation = floor for r >= 0
    iyD = (ry * 2.0 ** D).astype(np.int64)
    nroot_p = np.asarray(n_root, np.int64)[L]
    # rank: (level, score descending, index); FAST scores as int16 make both stable sorts radix sorts
    s = -np.asarray(score)[sel]
    s16 = s.astype(np.int16)
    key = s16 if np.array_equal(s16, s) else s
    by_score = np.argsort(key, kind="stable")
    by_rank = by_score[np.argsort(L[by_score].astype(np.int16), kind="stable")]   # point of each rank
    m = len(sel)
    rank = np.empty(m, np.int64)
    rank[by_rank] = np.arange(m)
    tree_lv = [i for i in range(n_lv) if tree[i]]
    seg = np.searchsorted(L, tree_lv)                                   # first point of each tree level
    bounds = np.append(seg, m)

    def node_keys(depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """(key of every point's node at its level's ``depth`` (per point), each level's first key,
        number of keys): keys offset per level so that nodes of different levels never meet."""
        sh = D - depth
        k = (iyD >> sh) * ((nroot_p << depth) + 1) + (ixD >> sh)
        span = np.maximum.reduceat(k, seg) + 1
        offs = np.concatenate([[0], np.cumsum(span)[:-1]])
        return k + np.repeat(offs, np.diff(bounds)), offs, int(span.sum())

    # each level's depth: the first from depth0 at which its occupied nodes reach the quota
    stop = {i: None for i in tree_lv}
    d = min(depth0[i] for i in tree_lv)
    while any(v is None for v in stop.values()):
        gk, offs, size = node_keys(np.full(m, d, np.int64))
        occupied = np.zeros(size, np.uint8)
        occupied[gk] = 1
        n_occ = np.add.reduceat(occupied, offs, dtype=np.int64)
        for j, i in enumerate(tree_lv):
            if stop[i] is None and d >= depth0[i] and (int(n_occ[j]) >= quotas[i] or d >= depth_cap[i]):
                stop[i] = d
        d += 1
    depth_p = np.asarray([stop[i] for i in tree_lv], np.int64)[np.searchsorted(tree_lv, L)]
    gk, _, size = node_keys(depth_p)
    best = np.full(size, m, np.int64)
    np.minimum.at(best, gk, rank)
    win_rank = np.zeros(m, bool)                                        # winners, marked in rank order
    win_rank[best[best < m]] = True
    win = by_rank[win_rank]
    n_win = np.bincount(L[win], minlength=n_lv)
    over = np.array([tree[i] and n_win[i] > quotas[i] for i in range(n_lv)])
    keep_win = win[~over[L[win]]]                                      # levels within quota: all winners
    out = parts + [sel[keep_win]]
    if over.any():
        # over quota: every parent node keeps its best, the rest of the quota by rank (quadtree_select)
        has_parent = (depth_p > 0) & over[L]
        pk, _, psize = node_keys(np.maximum(depth_p - 1, 0))
        pk = np.where(has_parent, pk, psize)                            # no parent: a key of its own
        pbest = np.full(psize + 1, m, np.int64)
        np.minimum.at(pbest, pk, rank)
        pbest[psize] = m
        is_pb = np.zeros(m, bool)
        is_pb[by_rank[pbest[pbest < m]]] = True
        rest_rank = win_rank & ~is_pb[by_rank] & over[L[by_rank]]     # in rank order: by level, then rank
        rest = by_rank[rest_rank]
        n_pb = np.bincount(L[is_pb], minlength=n_lv)
        room = np.asarray(quotas, np.int64) - n_pb
        Lr = L[rest]
        first = np.searchsorted(Lr, Lr)                                 # first rest point of its level
        keep_rest = rest[np.arange(len(rest)) - first < room[Lr]]
        out += [sel[np.flatnonzero(is_pb)], sel[keep_rest]]
    return np.sort(np.concatenate(out))


def ic_angles_levels(levels: list[np.ndarray], x: np.ndarray, y: np.ndarray, starts) -> np.ndarray:
    """``ic_angles`` of every level's points (level l: ``x[starts[l]:starts[l+1]]`` on ``levels[l]``):
    the patches of all levels gathered into one buffer, then one product with the circle's u / v
    masks. The moments are integers below 2^24, exact in float32 in any summation order."""
    n = int(starts[-1])
    if n == 0:
        return np.zeros(0, np.float32)
    w = 2 * HALF_PATCH + 1
    p = np.empty((n, w, w), np.uint8)
    for lvl, img in enumerate(levels):
        a, b = int(starts[lvl]), int(starts[lvl + 1])
        if b > a:
            # the patch of every pixel as a strided view (sliding_window_view's, without its checks)
            h, wd = img.shape
            s0, s1 = img.strides
            win = np.ndarray((h - w + 1, wd - w + 1, w, w), np.uint8, img, 0, (s0, s1, s0, s1))
            p[a:b] = win[y[a:b] - HALF_PATCH, x[a:b] - HALF_PATCH]
    m = np.einsum("kij,mij->km", p, MASK_UV)
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)


def keypoints_at(x: np.ndarray, y: np.ndarray, size: float, angles: np.ndarray) -> tuple:
    """``cv2.KeyPoint(x, y, size, angle)`` for every point, made by OpenCV in one call (no Python
    constructor per keypoint: 0.55 us each), the angles then set on them."""
    kps = cv2.KeyPoint_convert(np.column_stack([x, y]).astype(np.float32), float(size))
    for k, a in zip(kps, angles.tolist()):
        k.angle = a
    return kps
