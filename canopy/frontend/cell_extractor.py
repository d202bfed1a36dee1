"""ORB extraction as ORB-SLAM's ORBextractor does it: FAST per cell with a fallback threshold,
quadtree distribution per pyramid level, intensity-centroid orientation, rotated BRIEF.

Mur-Artal, Montiel, Tardós, "ORB-SLAM: a versatile and accurate monocular SLAM system", T-RO
2015, §III-A / ORB-SLAM2's ``ORBextractor::ComputeKeyPointsOctTree``: on every level of a scale
pyramid FAST runs in ~30 px cells at ``iniThFAST`` (20) and, in a cell where it finds nothing,
again at ``minThFAST`` (7); the corners are then spread by a quadtree to the level's quota
n (1 - f) / (1 - f^L) f^l (f = 1 / scale factor), one per node. cv2.ORB instead keeps the
strongest Harris corners of one FAST threshold per level, which on hazy, dark or noisy frames
empties the low-contrast parts of the image.

How it is done here (vectorised; no per-keypoint Python except setting the angles):

* FAST with non-maximum suppression once per level at the high threshold; cells left empty are
  found by ``np.bincount``; FAST at the fallback threshold runs on views of each run of adjacent
  empty cells (with FAST's 3 px border, and 1 px into a neighbouring non-empty cell so that
  non-maximum suppression sees what a view spanning the row's empty cells would).
  FAST's score (the largest threshold at which a pixel is still a corner) does not depend on the
  threshold, so a whole-level FAST followed by per-cell selection equals ORB-SLAM's per-cell
  calls up to non-maximum suppression across cell borders.
* The fallback threshold never goes below ``cell_fallback_noise_factor`` x the image noise sigma
  (``track_health.image_noise_sigma``, when the tracker measures noise: ``fast_noise_factor`` > 0):
  at 2 sigma a noise pixel rarely makes a FAST arc, so the fallback finds signal, not noise.
* Quadtree (on FAST scores, as ORB-SLAM) to twice the level's quota, then the quota's strongest
  by the Harris response (Harris & Stephens 1988, k = 0.04, 7x7 block of 3x3 Sobel gradients,
  as cv2.ORB ranks its twice-the-budget FAST corners), computed on gathered patches.
* Quadtree: the nodes at depth d are the cells of a regular 2^d subdivision of ORB-SLAM's root
  nodes, so the depth at which the occupied nodes first reach the quota is found by counting
  unique cell keys; every parent node keeps its best corner, the remaining slots of the quota go
  to the best of the children's winners (ORB-SLAM splits the most populated nodes first).
* Orientation: intensity centroid (Rosin 1999) in the circular patch of radius 15 (ORB's
  ``umax``), from gathered patches; descriptors: ``cv2.ORB.compute`` on each level with these
  angles (OpenCV keeps the given ``KeyPoint.angle``, tests/test_cell_extractor.py checks it).
  Both run once for all levels' selected corners (``canopy.frontend.cell_levels``: one patch
  gather and product per level into one array, one arctan2; ``cv2.KeyPoint`` objects from a
  pool): the same outputs as level by level (tests/test_cell_levels.py), ~11 % less CPU per
  KITTI image with the changes of docs/notes/s15-extract.md.

Coordinates follow cv2.ORB's convention (x_level * scale^level), so ``keypoint_centres`` and
stereo matching treat both extractors alike.
"""
from __future__ import annotations

from operator import attrgetter

import cv2
import numpy as np

from canopy.frontend.cell_levels import HALF_PATCH, MASK_UV, KeyPointPool, ic_angles_levels
from canopy.frontend.enhanced_extractor import EnhancedCellsRule
from canopy.frontend.features import Features, OrbExtractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.track_health import image_noise_sigma

HARRIS_K = 0.04
HARRIS_BLOCK = 7
FAST_BORDER = 3            # FAST needs 3 px around a pixel
_RESPONSE = attrgetter("response")


def _scores(kps) -> np.ndarray:
    """FAST scores (``KeyPoint.response``, integers 0..255) of keypoints as int16: read as Python
    floats into float64 (no conversion per item), then cast: 15 % less than reading into int16."""
    return np.fromiter(map(_RESPONSE, kps), np.float64, len(kps)).astype(np.int16)


def _fast_points(detector, view: np.ndarray, ox: int, oy: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """FAST corners of an image view: (x, y) contiguous int64 pixel coordinates offset by (ox, oy)
    and (K,) int16 scores (FAST's score is an integer 0..255: as int16 the quadtree's stable sort
    is a radix sort and needs no test of the floats first)."""
    kps = detector.detect(view)
    xy = np.asarray(cv2.KeyPoint_convert(kps), np.float32).reshape(-1, 2).T.astype(np.int64, order="C")
    xy += np.array([[ox], [oy]], np.int64)
    return xy[0], xy[1], _scores(kps)


def level_quotas(n_features: int, scale_factor: float, n_levels: int) -> np.ndarray:
    """Features per level, n (1 - f) / (1 - f^L) f^l with f = 1 / scale (ORB-SLAM); the last level
    takes the remainder so that the quotas add up to n."""
    f = 1.0 / scale_factor
    per = n_features * (1 - f) / (1 - f ** n_levels) if n_levels > 1 else float(n_features)
    q = np.array([int(round(per * f ** lvl)) for lvl in range(n_levels)], np.int64)
    q[-1] = max(n_features - int(q[:-1].sum()), 0)
    return q


_MASK_UV = MASK_UV                               # u (resp. v) inside ORB's circle, 0 outside
_HB = HARRIS_BLOCK // 2 + 1                      # patch half size incl. the Sobel border


def _patches(img: np.ndarray, x: np.ndarray, y: np.ndarray, half: int) -> np.ndarray:
    """(K, 2 half + 1, 2 half + 1) float32 patches centred on (x, y): whole patch rows are copied
    from a sliding-window view (2.5x faster than gathering every pixel by a flat index)."""
    n = 2 * half + 1
    return np.lib.stride_tricks.sliding_window_view(img, (n, n))[y - half, x - half].astype(np.float32)


def harris_responses(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Harris response of pixels (x, y) of ``img`` (7x7 block, 3x3 Sobel; cv2.ORB's scaling).
    The pixels must lie at least 4 px inside the image. (Shifted-array arithmetic, not a matrix
    product: small BLAS calls spawn OpenBLAS threads, which cost more than they save here.)"""
    if len(x) == 0:
        return np.zeros(0, np.float32)
    p = _patches(img, x, y, _HB)
    d = p[:, :, 2:] - p[:, :, :-2]                     # Sobel = central difference, then [1 2 1]
    dx = d[:, :-2] + 2 * d[:, 1:-1] + d[:, 2:]
    d = p[:, 2:] - p[:, :-2]
    dy = d[:, :, :-2] + 2 * d[:, :, 1:-1] + d[:, :, 2:]
    a = np.einsum("kij,kij->k", dx, dx)
    b = np.einsum("kij,kij->k", dy, dy)
    c = np.einsum("kij,kij->k", dx, dy)
    scale = 1.0 / (4 * HARRIS_BLOCK * 255.0)
    return ((a * b - c * c - HARRIS_K * (a + b) ** 2) * scale ** 4).astype(np.float32)


def ic_angles(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Orientation (degrees in [0, 360)) by the intensity centroid in ORB's circular patch of
    radius 15 (Rosin 1999; ORB / ORB-SLAM's IC_Angle). Pixels at least 15 px inside the image."""
    if len(x) == 0:
        return np.zeros(0, np.float32)
    n = 2 * HALF_PATCH + 1
    p = np.lib.stride_tricks.sliding_window_view(img, (n, n))[y - HALF_PATCH, x - HALF_PATCH]  # uint8
    # both moments in one einsum straight from the uint8 patches (einsum, not @: no OpenBLAS
    # threads for a small product). The moments are integers below 2^24, exact in float32 in any
    # summation order, so this equals two einsums over float32 copies at half the cost
    m = np.einsum("kij,mij->km", p, _MASK_UV)
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)


def quadtree_select(x: np.ndarray, y: np.ndarray, score: np.ndarray, x0: float, y0: float,
                    width: float, height: float, quota: int) -> np.ndarray:
    """Indices of at most ``quota`` points spread as ORB-SLAM's ``DistributeOctTree`` spreads
    them (best ``score`` per node), vectorised over depths of a regular quadtree. ``x``, ``y``:
    int or float arrays ((x - x0) / rw is the same float64 either way for pixel coordinates)."""
    n = len(x)
    if n <= quota:
        return np.arange(n)
    if quota <= 0:
        return np.zeros(0, np.int64)
    n_root = max(1, int(round(width / height)))           # ORB-SLAM's root nodes: ~square
    rw = width / n_root
    rx, ry = (x - x0) / rw, (y - y0) / height             # root-node units
    # rank of each point's score (0 = best): one sort serves every depth's best-per-node
    by_rank = np.argsort(_descending_key(score), kind="stable")   # point of each rank
    rank = np.empty(n, np.int64)
    rank[by_rank] = np.arange(n)
    # node keys by truncation when no point lies left of or above the region (the extractor's
    # never do): equal to the floor for non-negative values, one pass less per depth
    floor = not (len(rx) and rx.min() >= 0 and ry.min() >= 0)
    # depths below log4(quota / n_root) have fewer nodes than the quota: start there
    depth = max(0, int(np.floor(np.log(quota / n_root) / np.log(4.0))))
    prev_key = None if depth == 0 else _node_keys(rx, ry, n_root, depth - 1, floor)
    n_prev = 0 if prev_key is None else int(prev_key.max()) + 1
    while True:
        key = _node_keys(rx, ry, n_root, depth, floor)
        n_keys = int(key.max()) + 1
        occupied = np.zeros(n_keys, bool)
        occupied[key] = True
        if int(np.count_nonzero(occupied)) >= quota or rw / 2 ** depth < 1.0:
            break
        prev_key, n_prev = key, n_keys
        depth += 1
    # in rank space (index r = the point of rank r, by_rank[r]): the best of a node is its smallest
    # rank, and a list of ranks marked in a bool array comes out sorted by rank without a sort
    win = _best_ranks(key, rank, n_keys)
    if np.count_nonzero(win) <= quota:
        return np.sort(by_rank[win])
    # every parent node keeps its best (they are fewer than the quota), the rest by score: ORB-SLAM
    # splits the most populated nodes last in its final round, which ends at the quota
    if prev_key is None:
        parent = np.zeros(n, bool)
    else:
        parent = _best_ranks(prev_key, rank, n_prev)   # a parent's best is its child's best too
    rest = np.flatnonzero(win & ~parent)[: quota - int(np.count_nonzero(parent))]
    return np.sort(by_rank[np.concatenate([np.flatnonzero(parent), rest])])


def _best_ranks(key: np.ndarray, rank: np.ndarray, n_keys: int) -> np.ndarray:
    """(n,) bool indexed by rank: True at the best (smallest) rank of every key."""
    best = np.full(n_keys, len(rank), np.int64)
    np.minimum.at(best, key, rank)
    out = np.zeros(len(rank), bool)
    out[best[best < len(rank)]] = True
    return out


def _descending_key(score: np.ndarray) -> np.ndarray:
    """A key whose stable ascending sort is that of ``-score``. FAST scores are small integers
    (0..255, as float32 or int16): as int16, numpy's stable sort is a radix sort, ~10x faster than
    the merge sort of floats (~0.4 ms per 5 k corners); same order, ties in input order."""
    neg = -np.asarray(score)
    if neg.dtype == np.int16:   # the extractor's FAST scores (0..255): no test needed
        return neg
    if len(neg) and neg.dtype.kind == "f" and -32768 <= neg.min() and neg.max() <= 32767:
        as_int = neg.astype(np.int16)
        if np.array_equal(as_int, neg):
            return as_int
    return neg


def _node_keys(rx: np.ndarray, ry: np.ndarray, n_root: int, depth: int, floor: bool = True) -> np.ndarray:
    """Node key of every point at ``depth``; ``floor=False`` truncates (same for rx, ry >= 0)."""
    k = 2 ** depth
    if floor:
        return np.floor(ry * k).astype(np.int64) * (n_root * k + 1) + np.floor(rx * k).astype(np.int64)
    return (ry * k).astype(np.int64) * (n_root * k + 1) + (rx * k).astype(np.int64)


class CellExtractor:
    """ORB-SLAM-style ORB on one image; same interface and output as ``OrbExtractor``:
    ``extract(image, fast_threshold=None, fallback_threshold=None, min_keypoints=0)``.

    ``fast_threshold`` replaces the per-cell first threshold (the tracker's noise floor, or AFE
    Eq. 18). ``fallback_threshold`` is given only by the AFE rule on frames the enhancement
    changed: with ``extractor_enhanced: opencv`` those frames go to cv2.ORB (``OrbExtractor``);
    with ``cells`` it is the per-cell fallback. ``min_keypoints`` is unused (the fallback is per cell).

    ``responses=False`` (the tracker: stereo matching, map searches and keyframes read positions,
    octaves and descriptors only): with ``cell_ranking: fast`` the Harris responses rank nothing,
    so they are not computed and ``Features.response`` is all zeros (~3 ms per KITTI image). The
    other rankings need them and compute them anyway.
    """

    def __init__(self, params: TrackingParams, responses: bool = True):
        self.params = params
        self.responses = responses
        self.scale_factors = params.scale_factor ** np.arange(params.n_levels)
        self.quotas = level_quotas(params.n_features, params.scale_factor, params.n_levels)
        self.border = max(params.edge_threshold, HALF_PATCH + 1)
        self._fast = cv2.FastFeatureDetector_create(params.fast_threshold, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
        # one level per call: descriptors on our own pyramid level with our angles
        self._orb = cv2.ORB_create(nfeatures=max(int(self.quotas.max()), 1), scaleFactor=params.scale_factor,
                                   nlevels=1, edgeThreshold=params.edge_threshold, firstLevel=0, WTA_K=2,
                                   scoreType=cv2.ORB_HARRIS_SCORE, patchSize=params.patch_size)
        self._opencv = OrbExtractor(params) if params.extractor_enhanced == "opencv" else None
        self._enhanced_rule = EnhancedCellsRule(params) if self._opencv is not None else None
        self._keypoints = KeyPointPool(params.patch_size)  # the cv2.KeyPoints ORB.compute is given
        self._cells: dict = {}                              # cell look-up tables per level size
        self.last_stats: dict = {}

    def pyramid(self, image: np.ndarray) -> list[np.ndarray]:
        """Levels by cv2.resize of the previous level to round(size / scale^l), bit-exact
        interpolation: cv2.ORB's own pyramid, so descriptors equal cv2.ORB's on the same keypoints."""
        h, w = image.shape
        levels = [image]
        for s in self.scale_factors[1:]:
            levels.append(cv2.resize(levels[-1], (int(round(w / s)), int(round(h / s))),
                                     interpolation=cv2.INTER_LINEAR_EXACT))
        return levels

    def fallback_for(self, image: np.ndarray, fallback_threshold: int | None,
                     noise_sigma: float | None = None) -> tuple[int, float | None]:
        """(per-cell fallback threshold, the image noise sigma or None when not measured).
        ``noise_sigma``: ``image_noise_sigma(image)`` when the caller already measured it (the
        tracker does, for its FAST floor: 0.3 ms per KITTI image not spent twice)."""
        low = int(self.params.fast_fallback_threshold if fallback_threshold is None else fallback_threshold)
        sigma = None
        if self.params.fast_noise_factor > 0 and self.params.cell_fallback_noise_factor > 0:
            sigma = image_noise_sigma(image) if noise_sigma is None else float(noise_sigma)
            low = max(low, int(np.ceil(self.params.cell_fallback_noise_factor * sigma)))
        return min(low, 254), sigma

    def _fallback_corners(self, img: np.ndarray, empty: np.ndarray, low: int, x0: int, y0: int,
                          x1: int, y1: int, cw: int, ch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """FAST corners at ``low`` in the ``empty`` cells (nrow x ncol bool) of the detection region:
        (x, y, int16 scores).

        The corners are those of one FAST call per cell row on a view from the row's first to its
        last empty cell with FAST's 3 px border (ORB-SLAM calls FAST per cell, cells overlapping by
        that border), kept where they fall in an empty cell. FAST runs only on the runs of adjacent
        empty cells, though (on KITTI the row spans cover 54 % of a level, the empty cells 22 %):
        a corner's score does not depend on the view, and non-maximum suppression compares a
        corner with its 8 neighbours only, so a run's view reaching 1 px into the non-empty cell
        beside it (inside its row's span) gives the run's corners exactly as the span's view does.
        At the span's ends the view stops at the run, as the span's view does."""
        nrow, ncol = empty.shape
        padded = np.zeros((nrow, ncol + 2), np.int8)
        padded[:, 1:-1] = empty
        step = padded[:, 1:] - padded[:, :-1]
        rows, c_start = np.nonzero(step == 1)      # runs of empty cells, row-major: [c_start, c_end)
        c_end = np.nonzero(step == -1)[1]
        first = np.zeros(len(rows), np.int64)      # 1 where the run is not its row's first
        first[1:] = rows[1:] == rows[:-1]
        last = np.zeros(len(rows), np.int64)       # ... not its row's last
        last[:-1] = first[1:]
        ya = y0 + rows * ch
        yb = np.where(rows < nrow - 1, ya + ch, y1)
        xa = x0 + c_start * cw
        xb = np.where(c_end < ncol, x0 + c_end * cw, x1)
        va = xa - FAST_BORDER - first              # 1 px into the neighbouring non-empty cell
        vb = xb + FAST_BORDER + last
        self._fast.setThreshold(low)
        kps, counts = [], []
        detect = self._fast.detect
        for r0, r1, c0, c1 in zip((ya - FAST_BORDER).tolist(), (yb + FAST_BORDER).tolist(), va.tolist(), vb.tolist()):
            k = detect(img[r0:r1, c0:c1])
            kps += k
            counts.append(len(k))
        if not kps:
            e = np.zeros(0, np.int64)
            return e, e, np.zeros(0, np.int16)
        run = np.repeat(np.arange(len(counts)), counts)   # the run of every corner
        xy = np.asarray(cv2.KeyPoint_convert(kps), np.float32).reshape(-1, 2).T.astype(np.int64, order="C")
        px = xy[0] + va[run]
        py = xy[1] + (ya - FAST_BORDER)[run]
        score = _scores(kps)
        ok = np.flatnonzero((px >= xa[run]) & (px < xb[run]))
        px, py, score = px[ok], py[ok], score[ok]
        # row-major, as one FAST call per cell row returns them (the quadtree's ties keep input order)
        order = np.argsort(py * img.shape[1] + px, kind="stable")
        return px[order], py[order], score[order]

    def detect_level(self, img: np.ndarray, high: int, low: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
        """FAST corners of one level: (x, y int64 arrays, int16 FAST scores) with ``high`` in every cell and
        ``low`` in the cells where ``high`` found none; plus the detection region (x0, y0, w, h)."""
        h, w = img.shape
        b = self.border
        x0, y0, x1, y1 = b, b, w - b, h - b
        if x1 - x0 < 4 or y1 - y0 < 4:
            e = np.zeros(0, np.int64)
            return e, e, np.zeros(0, np.int16), (x0, y0, 0, 0)
        cs = self.params.cell_size
        ncol, nrow = max(1, (x1 - x0) // cs), max(1, (y1 - y0) // cs)
        cw, ch = int(np.ceil((x1 - x0) / ncol)), int(np.ceil((y1 - y0) / nrow))
        self._fast.setThreshold(int(high))
        x, y, score = _fast_points(self._fast, img[y0 - FAST_BORDER:y1 + FAST_BORDER, x0 - FAST_BORDER:x1 + FAST_BORDER],
                                   x0 - FAST_BORDER, y0 - FAST_BORDER)
        # OpenCV's FAST leaves the view's 3 px border out: all are inside, as a rule
        if len(x) and not (x.min() >= x0 and x.max() < x1 and y.min() >= y0 and y.max() < y1):
            keep = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
            x, y, score = x[keep], y[keep], score[keep]
        if low < high:
            row_cell, col_cell = self._cell_tables(h, w, x0, y0, cw, ch, nrow, ncol)
            empty = (np.bincount(row_cell[y] + col_cell[x], minlength=nrow * ncol) == 0).reshape(nrow, ncol)
            if empty.any():
                qx, qy, qs = self._fallback_corners(img, empty, int(low), x0, y0, x1, y1, cw, ch)
                x, y, score = np.concatenate([x, qx]), np.concatenate([y, qy]), np.concatenate([score, qs])
        return x, y, score, (x0, y0, x1 - x0, y1 - y0)

    def _cell_tables(self, h: int, w: int, x0: int, y0: int, cw: int, ch: int, nrow: int, ncol: int):
        """(row's cell index x ncol per pixel row, cell column per pixel column) of a level's cell grid,
        made once per level size: a corner's cell is two table look-ups and an add."""
        key = (h, w)
        tables = self._cells.get(key)
        if tables is None:
            rows = np.minimum(np.maximum(np.arange(h) - y0, 0) // ch, nrow - 1) * ncol
            cols = np.minimum(np.maximum(np.arange(w) - x0, 0) // cw, ncol - 1)
            tables = self._cells[key] = (rows, cols)
        return tables

    def extract(self, image: np.ndarray, fast_threshold: int | None = None,
                fallback_threshold: int | None = None, min_keypoints: int = 0,
                noise_sigma: float | None = None) -> Features:
        """``noise_sigma``: the image's ``image_noise_sigma`` if the caller measured it (else
        measured here when the fallback floor needs it)."""
        img = np.asarray(image) if image is not None else None
        if img is None or img.ndim != 2 or img.dtype != np.uint8 or img.size == 0:
            raise ValueError("CellExtractor.extract: image must be a non-empty 2-D uint8 grey image, got "
                             + ("None" if img is None else f"shape {img.shape} dtype {img.dtype}"))
        if fallback_threshold is not None and self._opencv is not None:
            cells_fallback = self._enhanced_rule.fallback(img, fast_threshold, fallback_threshold, noise_sigma)
            if cells_fallback is None:
                return self._opencv.extract(img, fast_threshold, fallback_threshold, min_keypoints)
            fallback_threshold = cells_fallback
        high = int(self.params.fast_threshold if fast_threshold is None else fast_threshold)
        low, sigma = self.fallback_for(img, fallback_threshold, noise_sigma)
        img = np.ascontiguousarray(img)
        levels = self.pyramid(img)
        # per level: FAST corners, spread to the level's quota (what is selected depends on the level alone)
        xs, ys, hs, lv = [], [], [], []
        n_candidates = 0
        for lvl, level in enumerate(levels):
            quota = int(self.quotas[lvl])
            if quota <= 0:
                continue
            x, y, fast_score, (rx, ry, rw, rh) = self.detect_level(level, high, low)
            n_candidates += len(x)
            if len(x) == 0:
                continue
            # quadtree on FAST scores to twice the quota (ORB-SLAM's DistributeOctTree), then the
            # strongest Harris responses of those (cv2.ORB's ranking of its 2x FAST retention) fill
            # the quota. A second quadtree on Harris instead keeps weaker corners in empty areas:
            # 20 % fewer stereo matches on KITTI 06 (docs/notes/s6-cells.md)
            rank = self.params.cell_ranking
            if rank == "harris2x":
                sel = quadtree_select(x, y, fast_score, rx, ry, rw, rh, 2 * quota)
                harris = harris_responses(level, x[sel], y[sel])
                keep = np.sort(np.argsort(-harris, kind="stable")[:quota])
                sel, harris = sel[keep], harris[keep]
            elif rank == "fast":  # ORB-SLAM as is: the best FAST score per node
                sel = quadtree_select(x, y, fast_score, rx, ry, rw, rh, quota)
                harris = harris_responses(level, x[sel], y[sel]) if self.responses else None
            else:  # "harris": the best Harris response per node
                harris = harris_responses(level, x, y)
                sel = quadtree_select(x, y, harris, rx, ry, rw, rh, quota)
                harris = harris[sel]
            xs.append(x[sel])
            ys.append(y[sel])
            hs.append(harris)
            lv.append(lvl)
        # then every level's keypoints at once: orientation, cv2.KeyPoints, descriptors per level
        # (ORB.compute on the level they were found on, with these angles)
        feats = self._describe(levels, xs, ys, hs, lv)
        self.last_stats = {"candidates": n_candidates, "fast_high": high, "fast_low": low, "noise_sigma": sigma}
        return feats

    def _describe(self, levels: list[np.ndarray], xs: list, ys: list, hs: list, lv: list) -> Features:
        """Features of the selected corners (``xs[i]``, ``ys[i]`` on pyramid level ``lv[i]``; ``hs[i]``
        their Harris responses or None for zeros): intensity-centroid angles of all levels in one
        pass (``cell_levels.ic_angles_levels``), the cv2.KeyPoints from the extractor's pool,
        ``ORB.compute`` per level."""
        if not xs:
            return Features.empty()
        counts = [len(x) for x in xs]
        starts = np.concatenate([[0], np.cumsum(counts)])
        x_all, y_all = np.concatenate(xs), np.concatenate(ys)
        angles = ic_angles_levels([levels[lvl] for lvl in lv], x_all, y_all, starts)
        kps_all = self._keypoints.keypoints(x_all, y_all, angles)
        keep, desc = [], []
        for i, lvl in enumerate(lv):
            a, b = int(starts[i]), int(starts[i + 1])
            kps, d = self._orb.compute(levels[lvl], kps_all[a:b])
            if d is None or len(kps) == 0:
                continue
            if len(kps) != b - a:  # OpenCV dropped some (border; it keeps the others' order): by position
                x, y, w = xs[i], ys[i], levels[lvl].shape[1]
                kept = np.asarray(cv2.KeyPoint_convert(kps), np.float32).reshape(-1, 2).astype(np.int64)
                keep.append(a + np.flatnonzero(np.isin(y * w + x, kept[:, 1] * w + kept[:, 0])))
            else:
                keep.append(np.arange(a, b))
            desc.append(d)
        if not desc:
            return Features.empty()
        idx = np.concatenate(keep)
        octave = np.repeat(np.asarray(lv, np.int32), counts)[idx]
        # float32 (x, y) times the level's scale as float32: what the per-level float32 * scale gave
        scale = self.scale_factors.astype(np.float32)[octave]
        uv = np.column_stack([x_all[idx], y_all[idx]]).astype(np.float32) * scale[:, None]
        if all(h is None for h in hs):
            response = np.zeros(len(idx), np.float32)
        else:
            response = np.concatenate([np.zeros(n, np.float32) if h is None else h for h, n in zip(hs, counts)])[idx]
        return Features(uv, octave, response, np.concatenate(desc), extractor="cells")


def make_extractor(params: TrackingParams, responses: bool = True):
    """The tracking extractor that ``params.extractor`` names (one per image: not thread-safe).
    ``responses=False``: for an image whose features only serve stereo matching (``CellExtractor``)."""
    return CellExtractor(params, responses) if params.extractor == "cells" else OrbExtractor(params)
