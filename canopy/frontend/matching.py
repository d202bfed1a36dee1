"""Vectorised binary-descriptor matching primitives.

Candidate generation never forms the full N x M product: references are sorted by
image row, each query gets a contiguous row band via ``searchsorted``, and the bands
are flattened into (query, reference) pairs with ``np.repeat``. Hamming distances of
the surviving pairs are computed in one batch (XOR + popcount on uint64 words).
"""
from __future__ import annotations

import threading

import numpy as np

if hasattr(np, "bitwise_count"):
    def _popcount64(x: np.ndarray) -> np.ndarray:
        return np.bitwise_count(x)
else:  # numpy < 2.0: 256-entry byte lookup table
    _LUT = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)

    def _popcount64(x: np.ndarray) -> np.ndarray:
        return _LUT[x.view(np.uint8)].reshape(*x.shape, 8).sum(-1)

DESCRIPTOR_BYTES = 32
# match_in_window's scaled search: reference scales merged into this many grids (see there). Recorded
# local-map searches, ms per call (load ~30): KITTI 5.34 with one grid per scale (8), 3.05 with 3, 3.11
# with 1; EuRoC (denser) 4.17, 4.03, 7.79: one grid finds 2.5-3.5x the pairs, 8 grids cost a ~10^5-cell
# table and query x 8 x 3 row ranges
SCALE_BANDS = 3


class _Scratch(threading.local):
    """Per-thread buffers for ``match_in_window``'s pair-sized temporaries, reused from call to call.

    Why: a fresh array for the ~10^4-10^5 pairs of a search is fresh memory (glibc hands blocks of
    this size back to the kernel when they are freed: munmap, or a trim of the heap top), and the
    first write to each of its pages is a page fault. On EuRoC that was ~400 faults and ~1.5 ms of
    each frame's ~5.4 ms of searches (getrusage minor faults, thread CPU; s19-mapsearch). One set
    per thread, as other threads (the stereo worker, loop closing) match at the same time; nothing
    returned ever points into them."""

    # pairs kept for reuse at most (~20 MB a thread); larger searches (loop closing's) allocate
    MAX_KEPT = 1 << 18

    def get(self, name: str, n: int, dtype, width: int = 0) -> np.ndarray:
        row = (width,) if width else ()
        if n > self.MAX_KEPT:
            return np.empty((n,) + row, dtype)
        buf = self.__dict__.get(name)
        if buf is None or len(buf) < n or buf.dtype != dtype or buf.shape[1:] != row:
            buf = np.empty((min(n + n // 4 + 1024, self.MAX_KEPT),) + row, dtype)   # room to grow a little
            self.__dict__[name] = buf
        return buf[:n]


_SCRATCH = _Scratch()


def floor_divide(a, b) -> np.ndarray:
    """``a // b`` for float arrays, the same values ~20x faster: numpy's float floor division
    goes through ``fmod`` (~25 ns per element), ``floor(a / b)`` does not. The correctly rounded
    quotient a / b is never below the exact quotient's floor k (k is representable), and it can
    reach k + 1 only by rounding up to exactly k + 1: so where a / b is not an integer, its floor
    is k, and where it is one (rare for pixel coordinates and cell sizes), numpy's ``//`` decides.
    Integer inputs go to ``//`` as they are."""
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind != "f" and b.dtype.kind != "f":
        return a // b
    q = np.true_divide(a, b)
    f = np.floor(q)
    exact = f == q           # integral (or infinite) quotients: possibly rounded up, so numpy's own
    if exact.any():          # (index arrays of the few: boolean indexes of broadcast views cost ~50 us)
        idx = np.nonzero(exact)
        f[idx] = np.broadcast_to(a, f.shape)[idx] // np.broadcast_to(b, f.shape)[idx]
    return f


def as_words(desc: np.ndarray) -> np.ndarray:
    """(N,32) uint8 ORB descriptors viewed as (N,4) uint64 words."""
    d = np.ascontiguousarray(desc, dtype=np.uint8).reshape(-1, DESCRIPTOR_BYTES)
    return d.view(np.uint64)


def hamming_pairs(words_a: np.ndarray, words_b: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """Hamming distance between rows words_a[ia] and words_b[ib] (int32)."""
    if len(ia) == 0:
        return np.zeros(0, np.int32)
    # np.take of whole rows is ~2x faster than fancy indexing of a 2-D array; XOR in place
    x = np.take(words_a, ia, axis=0)
    x ^= np.take(words_b, ib, axis=0)
    # the four words' counts added column by column: a reduction over an axis of length 4 runs
    # numpy's inner loop once per pair (~4x slower for the ~10^4-10^5 pairs of a frame); same sums
    dist = _popcount64(x[:, 0]).astype(np.int32)
    for i in range(1, x.shape[1]):
        dist += _popcount64(x[:, i])
    return dist


def _hamming_scratch(words_a: np.ndarray, words_b: np.ndarray, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """``hamming_pairs`` for valid indices, its row gathers and counts in ``_SCRATCH``."""
    n, w = len(ia), words_a.shape[1]
    if n == 0 or not hasattr(np, "bitwise_count"):
        return hamming_pairs(words_a, words_b, ia, ib)
    x = np.take(words_a, ia, axis=0, out=_SCRATCH.get("ham_a", n, words_a.dtype, w), mode="clip")
    x ^= np.take(words_b, ib, axis=0, out=_SCRATCH.get("ham_b", n, words_b.dtype, w), mode="clip")
    c = np.bitwise_count(x, out=_SCRATCH.get("ham_c", n, np.uint8, w))
    dist = c[:, 0].astype(np.int32)                  # column by column, as hamming_pairs
    for i in range(1, w):
        dist += c[:, i]
    return dist


def band_pairs(q_lo: np.ndarray, q_hi: np.ndarray, ref_key_sorted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (query i, sorted-reference j) with q_lo[i] <= ref_key_sorted[j] <= q_hi[i].

    Returns query indices and positions in the sorted reference array.
    """
    lo = np.searchsorted(ref_key_sorted, q_lo, side="left")
    hi = np.searchsorted(ref_key_sorted, q_hi, side="right")
    counts = np.maximum(hi - lo, 0)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    qi = np.repeat(np.arange(len(q_lo)), counts)
    starts = np.repeat(lo - np.cumsum(counts) + counts, counts)
    rj = starts + np.arange(total)
    return qi, rj


def best_two(qi: np.ndarray, rj: np.ndarray, dist: np.ndarray, n_query: int, second_ref: bool = False,
             tie_rank: np.ndarray | None = None):
    """Per query: best reference, its distance and the second-best distance.

    Returns (best_ref (n_query,) int64 with -1 where none, best_dist, second_dist) where
    missing distances are a large sentinel (1 << 20); with ``second_ref`` also the second-best
    reference (-1 where none) as a fourth array. Equal distances go to the earlier pair, or with
    ``tie_rank`` (one distinct rank per reference) to the reference of lower rank.
    """
    big = 1 << 20
    best_ref = np.full(n_query, -1, np.int64)
    best_d = np.full(n_query, big, np.int64)
    second_d = np.full(n_query, big, np.int64)
    second_r = np.full(n_query, -1, np.int64)
    if len(qi) == 0:
        return (best_ref, best_d, second_d, second_r) if second_ref else (best_ref, best_d, second_d)
    if tie_rank is not None:
        if not (len(qi) < 2 or bool(np.all(qi[1:] >= qi[:-1]))):
            raise ValueError("best_two: tie_rank needs pairs grouped by query")
        return _best_two_grouped(qi, rj, dist, best_ref, best_d, second_d, second_r, second_ref, tie_rank)
    if len(qi) > 1 and bool(np.all(qi[1:] >= qi[:-1])):
        return _best_two_grouped(qi, rj, dist, best_ref, best_d, second_d, second_r, second_ref)
    # one int64 key sorts by query, then by distance (distances are < 2**16)
    order = np.argsort(qi.astype(np.int64) * (1 << 16) + dist, kind="stable")
    qs, ds, rs = qi[order], dist[order], rj[order]
    first = np.ones(len(qs), bool)
    first[1:] = qs[1:] != qs[:-1]
    fidx = np.flatnonzero(first)
    best_ref[qs[fidx]] = rs[fidx]
    best_d[qs[fidx]] = ds[fidx]
    nxt = fidx + 1
    has_second = nxt < len(qs)
    has_second[has_second] = qs[nxt[has_second]] == qs[fidx[has_second]]
    second_d[qs[fidx[has_second]]] = ds[nxt[has_second]]
    if second_ref:
        second_r[qs[fidx[has_second]]] = rs[nxt[has_second]]
        return best_ref, best_d, second_d, second_r
    return best_ref, best_d, second_d


def _best_two_grouped(qi, rj, dist, best_ref, best_d, second_d, second_r, want_second_ref, tie_rank=None):
    """``best_two`` when the pairs come grouped by query (``qi`` non-decreasing, as
    ``band_pairs`` makes them): segment minima instead of a sort, O(n). Ties go to the earlier
    pair, as the stable sort does, or to the lower ``tie_rank`` of the reference."""
    n = len(qi)
    change = np.empty(n, bool)          # (np.r_ would parse its arguments in Python: ~40 us a call)
    change[0] = True
    np.not_equal(qi[1:], qi[:-1], out=change[1:])
    starts = np.flatnonzero(change)
    q = qi[starts]
    if tie_rank is None:
        m, tie = n, np.arange(n, dtype=np.int64)
    else:
        m, tie = len(tie_rank), np.asarray(tie_rank, np.int64)[rj]
        lengths = np.empty_like(starts)             # (np.diff(append=) costs ~30 us in Python)
        np.subtract(starts[1:], starts[:-1], out=lengths[:-1])
        lengths[-1] = n - starts[-1]
    key = dist.astype(np.int64)                     # distance first, then position (or rank)
    key *= m
    key += tie
    best_key = np.minimum.reduceat(key, starts)
    if tie_rank is None:
        best_pos = best_key % n
    else:  # the pair of each segment holding its minimum key (keys are distinct within a segment)
        best_pos = np.flatnonzero(key == np.repeat(best_key, lengths))
    best_ref[q] = rj[best_pos]
    best_d[q] = best_key // m
    key[best_pos] = np.iinfo(np.int64).max          # the runner-up: minimum of the rest
    sec_key = np.minimum.reduceat(key, starts)
    has = sec_key != np.iinfo(np.int64).max
    second_d[q[has]] = sec_key[has] // m
    if want_second_ref:
        if tie_rank is None:
            second_r[q[has]] = rj[sec_key[has] % n]
        else:
            sec_pos = np.flatnonzero(key == np.repeat(sec_key, lengths))
            second_r[qi[sec_pos]] = rj[sec_pos]
        return best_ref, best_d, second_d, second_r
    return best_ref, best_d, second_d


def unique_by_reference(query_idx: np.ndarray, ref_idx: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Boolean mask keeping, for every reference used by several queries, only the closest."""
    if len(query_idx) == 0:
        return np.zeros(0, bool)
    order = np.argsort(ref_idx.astype(np.int64) * (1 << 16) + dist, kind="stable")
    keep_sorted = np.ones(len(order), bool)
    r = ref_idx[order]
    keep_sorted[1:] = r[1:] != r[:-1]
    keep = np.zeros(len(order), bool)
    keep[order[keep_sorted]] = True
    return keep


def grid_pairs(q_uv: np.ndarray, r_uv: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """(query, reference) pairs whose grid cells (side ``cell``) are 8-neighbours.

    References are sorted by cell id = row * n_cols + col, so the three cells of one grid
    row around a query are one contiguous key range: three ``band_pairs`` calls cover the
    3x3 neighbourhood, which contains every reference within ``cell`` of the query.
    """
    cell = max(cell, 1.0)
    lo_uv = np.minimum(q_uv.min(axis=0), r_uv.min(axis=0))
    n_cols = int((max(q_uv[:, 0].max(), r_uv[:, 0].max()) - lo_uv[0]) // cell) + 3
    rc = floor_divide(r_uv - lo_uv, cell).astype(np.int64)
    rkey = rc[:, 1] * n_cols + rc[:, 0]
    order = np.argsort(rkey, kind="stable")
    rkey_sorted = rkey[order]
    qc = floor_divide(q_uv - lo_uv, cell).astype(np.int64)
    col_lo = np.maximum(qc[:, 0] - 1, 0)
    col_hi = qc[:, 0] + 1
    qis, rjs = [], []
    for dy in (-1, 0, 1):
        row = qc[:, 1] + dy
        lo = np.where(row >= 0, row * n_cols + col_lo, 1)
        hi = np.where(row >= 0, row * n_cols + col_hi, 0)
        qi, rpos = band_pairs(lo, hi, rkey_sorted)
        qis.append(qi)
        rjs.append(order[rpos])
    return np.concatenate(qis), np.concatenate(rjs)


def _column_range(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``uv.min(axis=0)``, ``uv.max(axis=0)`` of (N,2) coordinates, column by column: the same
    values and dtype (a minimum is exact in any order; NaN propagates either way), ~4x cheaper
    (a reduction over axis 0 of an (N,2) array runs numpy's inner loop over 2 elements N times;
    4 of them were ~0.25 ms of each local-map search on KITTI, issue 8)."""
    c0, c1 = uv[:, 0], uv[:, 1]
    return np.array([c0.min(), c1.min()], uv.dtype), np.array([c0.max(), c1.max()], uv.dtype)


def _grouped_grid(q_uv: np.ndarray, r_uv: np.ndarray, r_group: np.ndarray, cells: np.ndarray):
    """The cell keys of ``grid_pairs_grouped``: (cells, grid origin, columns per group, cells per
    group, each group's key of the origin's cell, the references' keys). A group's grid has one empty
    row and column on each side of its points' cells, so every query's 3 x 3 cells are inside it."""
    cells = np.maximum(np.asarray(cells, float), 1.0)
    q_lo, q_hi = _column_range(q_uv)
    r_lo, r_hi = _column_range(r_uv)
    lo_uv = np.minimum(q_lo, r_lo)
    span = np.maximum(q_hi, r_hi) - lo_uv
    n_cols = (span[0] // cells).astype(np.int64) + 3
    n_rows = (span[1] // cells).astype(np.int64) + 3
    sizes = n_cols * n_rows
    origin = np.cumsum(sizes) - sizes + n_cols + 1        # group g's cell (row 1, column 1)
    rc = floor_divide(r_uv - lo_uv, cells[r_group][:, None]).astype(np.int64)
    rkey = origin[r_group] + rc[:, 1] * n_cols[r_group] + rc[:, 0]
    return cells, lo_uv, n_cols, sizes, origin, rkey


def grid_rank(q_uv: np.ndarray, r_uv: np.ndarray, r_group: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Each reference's rank in the order ``grid_pairs_grouped`` lists one query's pairs in (by
    cell key, then reference index): with it as ``best_two``'s ``tie_rank``, any superset of that
    function's pairs, grouped by query, resolves equal distances as its pairs would."""
    _, _, _, sizes, _, rkey = _grouped_grid(q_uv, r_uv, r_group, cells)
    rank = np.empty(len(rkey), np.int64)
    rank[_stable_order(rkey, int(sizes.sum()))] = np.arange(len(rkey))
    return rank


def _stable_order(keys: np.ndarray, n_keys: int) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` of keys in [0, n_keys): the same permutation, and with
    fewer than 2^16 keys a radix sort (numpy's stable sort of 16-bit integers), ~4x cheaper than
    its timsort of int64 for the ~10^3 keypoints of a frame."""
    if n_keys <= 1 << 16:
        keys = keys.astype(np.uint16)
    return np.argsort(keys, kind="stable")


def _grid_ranges(q_uv: np.ndarray, r_uv: np.ndarray, r_group: np.ndarray, cells: np.ndarray):
    """The references' cell order and, per query, its 3 x n_groups ranges of positions in that
    order (see ``grid_pairs_grouped``): (order, lo (Q, 3G), counts (Q, 3G))."""
    cells, lo_uv, n_cols, sizes, origin, rkey = _grouped_grid(q_uv, r_uv, r_group, cells)
    order = _stable_order(rkey, int(sizes.sum()))
    start = np.zeros(int(sizes.sum()) + 1, np.int64)   # start[k]: references with a key < k
    np.cumsum(np.bincount(rkey, minlength=len(start) - 1), out=start[1:])
    qc = floor_divide((q_uv - lo_uv)[:, None, :], cells[None, :, None]).astype(np.int64)    # (Q,G,2)
    # each query's cell key per group; its 3 x 3 cells lie inside the group's grid (the empty border),
    # so the rows below, at and above it are the key ranges [key - 1, key + 2) moved by one row
    key = origin + qc[:, :, 1] * n_cols + qc[:, :, 0]                                  # (Q,G)
    first = (key - 1)[:, :, None] + np.arange(-1, 2) * n_cols[:, None]                # (Q,G,3)
    lo = start[first]
    counts = start[first + 3]
    counts -= lo
    return order, lo.reshape(len(q_uv), -1), counts.reshape(len(q_uv), -1)


def _range_pairs(lo: np.ndarray, counts: np.ndarray):
    """The pairs of ``_grid_ranges``' ranges: (query per pair, position in the cell order per pair,
    pairs per query). A query's ranges are consecutive, so its pairs are one ``repeat`` by its total."""
    per_query = counts.sum(axis=1)
    total = int(per_query.sum())
    query = np.repeat(np.arange(len(lo)), per_query)
    c = counts.reshape(-1)
    rpos = np.repeat(lo.reshape(-1) - np.cumsum(c) + c, c)
    rpos += np.arange(total)
    return query, rpos, per_query


def _steps_cumsum(out: np.ndarray, at: np.ndarray, jumps: np.ndarray, step: int) -> np.ndarray:
    """``out`` := the running sum of ``step`` everywhere except ``jumps`` at positions ``at``: runs
    of consecutive values in place (``np.repeat`` has no ``out``; integers, so exact)."""
    out.fill(step)
    out[at] = jumps
    return np.cumsum(out, out=out)


def _range_pairs_scratch(lo: np.ndarray, counts: np.ndarray, total: int):
    """``_range_pairs``' (query, position) arrays, in ``_SCRATCH`` (``total`` > 0 pairs)."""
    c = counts.reshape(-1)
    nz = np.flatnonzero(c != 0)                      # (of a bool array: ~2x cheaper than of ints)
    c_nz, lo_nz = c[nz], lo.reshape(-1)[nz]
    first = np.cumsum(c_nz) - c_nz                   # each non-empty range's first pair
    jump = np.empty(len(nz), np.int64)               # its first position minus the last one before
    jump[0] = lo_nz[0]
    jump[1:] = lo_nz[1:] - (lo_nz[:-1] + c_nz[:-1] - 1)
    rpos = _steps_cumsum(_SCRATCH.get("rpos", total, np.int64), first, jump, 1)
    per_query = counts.sum(axis=1)
    qz = np.flatnonzero(per_query)                   # queries with pairs: the query steps up there
    q_first = np.cumsum(per_query[qz]) - per_query[qz]
    query = _steps_cumsum(_SCRATCH.get("query", total, np.int64), q_first, np.diff(qz, prepend=0), 0)
    return query, rpos


def grid_pairs_grouped(q_uv: np.ndarray, r_uv: np.ndarray, r_group: np.ndarray,
                       cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``grid_pairs`` for references in groups, group g on its own grid of cell side
    ``cells[g]`` (e.g. one group per pyramid level, the cell scaled with the level): every
    (query, reference) pair whose cells on the reference's grid are 8-neighbours. All groups'
    cells share one key space, so the 3 x n_groups row ranges of every query are searched in one
    ``band_pairs`` call instead of one ``grid_pairs`` per group.

    The key space is small (a few 10^4 cells), so the row ranges are read from a dense table of
    cell starts (counting sort: ``bincount`` + ``cumsum``) instead of two binary searches per
    range; the pairs, and their order (by query, then key, then reference index), are those of
    the binary search."""
    order, lo, counts = _grid_ranges(q_uv, r_uv, r_group, cells)
    query, rpos, _ = _range_pairs(lo, counts)
    return query, order[rpos]


def match_in_window(q_uv: np.ndarray, q_words: np.ndarray, q_radius: np.ndarray,
                    r_uv: np.ndarray, r_words: np.ndarray, max_hamming: int, ratio: float,
                    q_mask: np.ndarray | None = None, r_scale: np.ndarray | None = None,
                    r_level: np.ndarray | None = None):
    """Match each query (e.g. a projected landmark) to the reference keypoint inside a circle.

    Candidates come from the 3x3 grid cells around the query, then a circle test; best Hamming
    distance <= max_hamming with best < ratio * second (Lowe ratio, as ORB-SLAM's
    SearchByProjection); each reference keypoint is kept for its closest query only.
    ``r_scale`` optionally widens the circle per reference keypoint (its octave scale, as
    ORB-SLAM scales the search window with the pyramid level). With ``r_level`` (the reference
    keypoints' pyramid levels) the ratio test applies only when the two best candidates sit on
    the same level, as ORB-SLAM's SearchByProjection for the local map: a similar corner on
    another level is not an ambiguity, it is the same structure at another scale.
    Returns (query indices, reference indices, distances).
    """
    n_q = len(q_uv)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    if n_q == 0 or len(r_uv) == 0:
        return empty
    if q_mask is not None:
        sel = np.flatnonzero(q_mask)
    else:
        sel = np.arange(n_q)
    if len(sel) == 0:
        return empty
    q_sel = q_uv[sel]
    q_rad = q_radius[sel]
    rmax = float(np.max(q_rad))
    tie_rank = None
    if r_scale is None:
        order, lo, counts = _grid_ranges(q_sel, r_uv, np.zeros(len(r_uv), np.int64), np.array([rmax]))
    else:
        # The pairs within the scaled radii are the pairs of one grid per reference scale (cells of
        # rmax x scale), and equal distances go to the earlier pair of that grid's order. Those
        # grids' cell table (~10^5 cells on KITTI) and query x scale x 3 row ranges cost more than
        # the pairs, ~90 % of the ranges being empty: SCALE_BANDS grids, each with the cell of the
        # widest scale in its band, find a superset (a band's 3x3 cells hold every pair within its
        # widest radius; the extra pairs fail the circle test below), and the per-scale grids'
        # order only ranks the references (``grid_rank``) for ``best_two``'s ties: the same matches
        scales, group = np.unique(r_scale, return_inverse=True)
        group = group.reshape(-1)
        n_bands = min(SCALE_BANDS, len(scales))
        if n_bands == len(scales):
            order, lo, counts = _grid_ranges(q_sel, r_uv, group, rmax * scales)
        else:
            tie_rank = grid_rank(q_sel, r_uv, group, rmax * scales)
            band = np.arange(len(scales)) * n_bands // len(scales)
            band_cells = rmax * scales[np.flatnonzero(np.diff(band, append=n_bands))]  # each band's widest
            order, lo, counts = _grid_ranges(q_sel, r_uv, band[group], band_cells)
            tie_rank = tie_rank[order]
    # From here the references are addressed by their position in the grid's cell order (``rpos``)
    # and the queries by their position in ``sel``: the references' coordinates, words, scales and
    # levels are put in that order once (~10^3 rows) instead of gathering through ``order`` and
    # ``sel`` for every one of the ~10^4-10^5 pairs; the pairs keep their order (by query, then cell
    # order), so equal distances go to the same pair, and the few matches map back at the end. The
    # pair-sized arrays live in ``_SCRATCH`` (page faults, see there) until the circle test is done.
    total = int(counts.sum())
    if total == 0:
        return empty
    qi, rpos = _range_pairs_scratch(lo, counts, total)
    # the circle test, per coordinate (gathers of 2-D rows cost ~3x more), in place; the same
    # arithmetic (dtype, operations) as ((q - r) ** 2).sum(axis=1) <= (radius [x scale]) ** 2
    dt = np.result_type(q_uv, r_uv)
    r_sorted = np.take(r_uv, order, axis=0)
    d2, dv, tmp = (_SCRATCH.get(name, total, dt) for name in ("d2", "dv", "tmp"))
    for d, col in ((d2, 0), (dv, 1)):       # (mode="clip": no buffered copy; the indices are valid)
        np.take(np.ascontiguousarray(q_sel[:, col], dt), qi, out=d, mode="clip")
        np.take(np.ascontiguousarray(r_sorted[:, col], dt), rpos, out=tmp, mode="clip")
        d -= tmp
        d *= d
    d2 += dv
    ok = _SCRATCH.get("ok", total, bool)
    if q_rad.min() == q_rad.max():
        # one radius for all queries (the tracker's searches): its square per reference scale, the
        # same per-element products as q_radius[qi] * r_scale[rj] squared
        rad = q_rad[:1] if r_scale is None else q_rad[:1] * r_scale[order]
        rad = rad * rad
        if r_scale is not None:
            rad = np.take(rad, rpos, out=_SCRATCH.get("rad", total, rad.dtype), mode="clip")
        np.less_equal(d2, rad, out=ok)
    else:
        rad = q_rad[qi]
        if r_scale is not None:
            rad = rad * r_scale[order][rpos]
        np.less_equal(d2, rad * rad, out=ok)
    kept = np.flatnonzero(ok)        # (a boolean index of the ~5*10^4 pairs is ~3x slower than these)
    qi, rpos = np.take(qi, kept), np.take(rpos, kept)
    dist = _hamming_scratch(np.take(q_words, sel, axis=0), np.take(r_words, order, axis=0), qi, rpos)
    best_ref, best_d, second_d, second_r = best_two(qi, rpos, dist, len(sel), second_ref=True, tie_rank=tie_rank)
    ambiguous = best_d >= ratio * second_d
    if r_level is not None:
        level = r_level[order]
        ambiguous &= (second_r >= 0) & (level[np.maximum(second_r, 0)] == level[np.maximum(best_ref, 0)])
    good = np.flatnonzero((best_ref >= 0) & (best_d <= max_hamming) & ~ambiguous)
    qsel = sel[good]
    rsel = order[best_ref[good]]
    dsel = best_d[good]
    keep = unique_by_reference(qsel, rsel, dsel)
    return qsel[keep], rsel[keep], dsel[keep]


def knn_match(q_desc: np.ndarray, r_desc: np.ndarray, max_hamming: int, ratio: float):
    """Brute-force Hamming matching with Lowe's ratio test (OpenCV BFMatcher, k = 2), each
    reference used once. For when no pose prediction is available."""
    import cv2

    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(q_desc) < 2 or len(r_desc) < 2:
        return empty
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(np.ascontiguousarray(q_desc), np.ascontiguousarray(r_desc), k=2)
    arr = np.array([(m[0].queryIdx, m[0].trainIdx, m[0].distance, m[1].distance) for m in knn if len(m) == 2])
    if len(arr) == 0:
        return empty
    good = (arr[:, 2] <= max_hamming) & (arr[:, 2] < ratio * arr[:, 3])
    q, r, d = arr[good, 0].astype(np.int64), arr[good, 1].astype(np.int64), arr[good, 2].astype(np.int64)
    keep = unique_by_reference(q, r, d)
    return q[keep], r[keep], d[keep]
