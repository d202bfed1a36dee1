"""The cell extractor's per-level steps done for all pyramid levels at once (issue 8, speed).

``CellExtractor`` spreads each level's FAST corners with ``quadtree_select`` (ORB-SLAM's
``DistributeOctTree``), orients them with ``ic_angles`` (Rosin's intensity centroid) and hands them
to ``cv2.ORB.compute`` as ``cv2.KeyPoint`` objects. Done level by level, the orientation's ~15 numpy
calls per level cost more than their work on the small levels (a KITTI image's level 7 keeps 122
corners, level 0 434): here one gather and product per level into one array, one arctan2 for all. The
keypoints come from a pool instead of one constructor call each. The outputs equal the per-level
code's (tests/test_cell_levels.py: the extractor against a written-out per-level reference).

Levels are contiguous segments of the point arrays: level l holds points ``starts[l]:starts[l+1]``.
"""
from __future__ import annotations

from collections import deque
from itertools import repeat

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


def ic_angles_levels(levels: list[np.ndarray], x: np.ndarray, y: np.ndarray, starts) -> np.ndarray:
    """``ic_angles`` of every level's points (level l: ``x[starts[l]:starts[l+1]]`` on ``levels[l]``):
    each level's patches as one gather from a strided view of all its patches (sliding_window_view's,
    without its checks), their two moments by one product with the circle's u / v masks written
    into one (K, 2) array, then one arctan2 for all. The moments are integers below 2^24, exact in
    float32 in any summation order. (Gathering all levels into one buffer first for a single product
    costs a 1.9 MB copy: 5 % more.)"""
    n = int(starts[-1])
    if n == 0:
        return np.zeros(0, np.float32)
    w = 2 * HALF_PATCH + 1
    m = np.empty((n, 2), np.float32)
    for lvl, img in enumerate(levels):
        a, b = int(starts[lvl]), int(starts[lvl + 1])
        if b > a:
            h, wd = img.shape
            s0, s1 = img.strides
            win = np.ndarray((h - w + 1, wd - w + 1, w, w), np.uint8, img, 0, (s0, s1, s0, s1))
            # uint8 patches straight into einsum (einsum, not @: no OpenBLAS threads)
            np.einsum("kij,mij->km", win[y[a:b] - HALF_PATCH, x[a:b] - HALF_PATCH], MASK_UV, out=m[a:b])
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)


class KeyPointPool:
    """``cv2.KeyPoint`` objects made once and reused: ``ORB.compute`` copies the keypoints it is given
    (its output is new objects), so setting ``pt`` and ``angle`` on kept ones per image gives it the
    same input as new ``cv2.KeyPoint(x, y, size, angle)`` objects at half the cost (the constructor
    parses its arguments, ~0.55 us per keypoint; ``KeyPoint_convert`` from points is slower still).
    One pool per extractor: not for two threads at once (neither is the extractor)."""

    def __init__(self, size: float):
        self.size = float(size)
        self._pool: list = []

    def keypoints(self, x: np.ndarray, y: np.ndarray, angles: np.ndarray) -> list:
        """Keypoints at (x, y) with ``angles`` (degrees), size ``size``; valid until the next call."""
        n = len(x)
        if n > len(self._pool):
            self._pool += map(cv2.KeyPoint, repeat(0.0, n - len(self._pool)), repeat(0.0), repeat(self.size))
        kps = self._pool[:n]
        # map over the setter, not a loop: no Python frame per keypoint
        deque(map(setattr, kps, repeat("pt", n), zip(x.tolist(), y.tolist())), maxlen=0)
        deque(map(setattr, kps, repeat("angle", n), angles.tolist()), maxlen=0)
        return kps
