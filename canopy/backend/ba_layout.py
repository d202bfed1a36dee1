"""The layout of a local bundle adjustment's edges, for ``canopy.backend.stereo_ba``'s
Levenberg-Marquardt: the window's observations (``StereoEdges``), their orders by pose and by point
(``_ByPose``, ``_Groups``, ``_Structure``: built once per BA call, the window's structure does not
change inside it) and the per-thread work arrays reused across iterations and calls (``_Work``:
fresh temporaries of ~10^4 rows faulted their pages in at every step, s19-bacost).

Split from ``stereo_ba`` (the solver: projection, robust cost, Jacobians, Schur blocks, LM loop) to
keep each room small; ``stereo_ba`` re-exports these names.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

POINTS_PER_CHUNK = 32   # rows of the Schur reduction's products (see _Structure.point_major)


@dataclass
class StereoEdges:
    """Observations of the window: edge e sees point ``point[e]`` from pose ``pose[e]``."""

    pose: np.ndarray     # (E,) int index into the pose array (local poses first, then fixed)
    point: np.ndarray    # (E,) int index into the point array
    meas: np.ndarray     # (E,3) u_left, v, u_right (u_right ignored where not stereo)
    stereo: np.ndarray   # (E,) bool
    sigma: np.ndarray    # (E,) px
    huber: np.ndarray    # (E,) Huber width in whitened units

    def take(self, idx: np.ndarray) -> "StereoEdges":
        """The edges ``idx`` (indices, or a boolean mask over the edges), in that order."""
        idx = np.flatnonzero(idx) if np.asarray(idx).dtype == bool else np.asarray(idx)
        return StereoEdges(self.pose[idx], self.point[idx], np.take(self.meas, idx, axis=0), self.stereo[idx],
                           self.sigma[idx], self.huber[idx])


_GEMV_ORDER = [1, 0, 2]   # the order in which OpenBLAS's 3x3 GEMV sums its products (see _ByPose.rotate)


class _ByPose:
    """All edges by pose, for the products with the pose's rotation: one GEMM per pose over its edges
    stacked, where numpy's batched matmul / matvec made one BLAS call per edge (~30 ns each, ~6 k
    edges per KITTI projection, issue 8). OpenBLAS sums a GEMM's products in one FMA chain along the
    inner index, as in the per-edge calls: the same bytes (tests/test_ba_cost.py)."""

    def __init__(self, edges: StereoEdges):
        self.order = _stable_order(edges.pose)
        keys = edges.pose[self.order]
        starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if len(keys) else np.zeros(0, np.int64)
        ends = np.r_[starts[1:], len(keys)]
        self.runs = list(zip(keys[starts].tolist(), starts.tolist(), ends.tolist()))
        self.inverse = np.empty_like(self.order)
        self.inverse[self.order] = np.arange(len(self.order))
        self.point = edges.point[self.order]
        self.stereo = edges.stereo[self.order].astype(float)   # what ``Jp[:, 2, :] *= edges.stereo`` multiplies by

    def rotate(self, R: np.ndarray, X: np.ndarray, out: np.ndarray, work: "_Work") -> np.ndarray:
        """out[e] = R[pose e] X[point e] (E,3) as ``np.matvec`` gives it: OpenBLAS's 3x3 GEMV sums the
        products of columns 1, 0, 2 in that order, so the GEMM takes them in that order. numpy makes a
        (1x3)(3x3) product a GEMV of another shape: a pose's only edge keeps ``np.matvec``."""
        Xs = _take(np.ascontiguousarray(X[:, _GEMV_ORDER]), self.point, work.get("X_by_pose", out.shape))
        Ps = work.get("RX_by_pose", out.shape)
        for k, a, b in self.runs:
            if b - a > 1:
                np.matmul(Xs[a:b], R[k][:, _GEMV_ORDER].T, out=Ps[a:b])
            else:
                Ps[a] = _mv(R[k], X[self.point[a]])
        return _take(Ps, self.inverse, out)

    def rotate_jacobians(self, Jp: np.ndarray, R: np.ndarray, out: np.ndarray, work: "_Work") -> np.ndarray:
        """out[e] = Jp[e] R[pose e] (E,3,3) for ``Jp`` in the pose order, as ``Jp @ R`` per edge gives it
        (the same 3x3 inner products, one FMA chain each), back in the edges' order."""
        Js = work.get("Jx_by_pose", out.shape)
        for k, a, b in self.runs:
            np.matmul(Jp[a:b].reshape(-1, 3), R[k], out=Js[a:b].reshape(-1, 3))
        return _take(Js, self.inverse, out)


class _Work:
    """Work arrays by name, kept from one BA call to the next in a thread (``_work``): they replace
    ~30 temporaries of 0.1-1.7 MB per LM iteration, which glibc maps afresh, so that their pages
    fault in (~0.8 ms system CPU per KITTI call; ~3 ms if kept for one call only, issue 8). An array
    asked ``zero`` is zeroed at its first use in a call (``begin``); its users write the same
    entries at every iteration of the call, so the others stay zero."""

    def __init__(self):
        self._flat: dict[str, np.ndarray] = {}
        self._zeroed: set[str] = set()

    def begin(self) -> "_Work":
        """Start a BA call."""
        self._zeroed.clear()
        return self

    def get(self, name: str, shape: tuple, zero: bool = False) -> np.ndarray:
        n = math.prod(shape)
        flat = self._flat.get(name)
        if flat is None or len(flat) < n:
            flat = self._flat[name] = np.empty(n + n // 4)   # room for a somewhat larger next window
        a = flat[:n].reshape(shape)
        if zero and name not in self._zeroed:
            a.fill(0.0)
            self._zeroed.add(name)
        return a


_THREAD = threading.local()


def _work() -> _Work:
    """This thread's work arrays (a BA call runs in one thread; two threads never share them)."""
    w = getattr(_THREAD, "work", None)
    if w is None:
        w = _THREAD.work = _Work()
    return w


def _stable_order(keys: np.ndarray) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` (a stable order is unique); keys below 2^16 as uint16,
    which numpy sorts by radix (~6x faster than int64 on ~6 k pose indices)."""
    if len(keys) and 0 <= keys.min() and keys.max() < 1 << 16:
        keys = keys.astype(np.uint16)
    return np.argsort(keys, kind="stable")


def _take(a: np.ndarray, idx: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``np.take(a, idx, axis=0)`` into ``out`` (``mode="clip"``: unbuffered; the indices are valid)."""
    return np.take(a, idx, axis=0, out=out, mode="clip")


class _Groups:
    """Sums of per-item blocks by an integer key in [0, n), with the grouping computed once (the
    edges of a BA keep their poses and points through all iterations): a sort, then
    ``np.add.reduceat`` over contiguous runs. (Gathers along the first axis here and below use
    ``np.take``: the same values as fancy indexing, 2-4x faster on ~7 k small blocks.)"""

    def __init__(self, keys: np.ndarray, n: int):
        self.order = _stable_order(keys)
        ks = keys[self.order]
        self.starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]]) if len(ks) else np.zeros(0, np.int64)
        self.keys = ks[self.starts]
        self.ends = np.r_[self.starts[1:], len(ks)]
        self.n = n
        # local BA's edges come sorted by point (``_observation_edges``: by landmark id), and every
        # point has an edge: then the sums need neither the reordering gather nor the scatter
        self.in_order = bool(np.array_equal(self.order, np.arange(len(keys))))
        self.all_keys = bool(np.array_equal(self.keys, np.arange(n)))

    def sum(self, blocks: np.ndarray, presorted: bool = False) -> np.ndarray:
        if not len(self.starts):
            return np.zeros((self.n,) + blocks.shape[1:])
        b = blocks if presorted or self.in_order else np.take(blocks, self.order, axis=0)
        sums = np.add.reduceat(b.reshape(len(b), -1), self.starts, axis=0).reshape(
            (len(self.starts),) + blocks.shape[1:])
        if self.all_keys:
            return sums
        out = np.zeros((self.n,) + blocks.shape[1:])
        out[self.keys] = sums
        return out


@dataclass
class _Structure:
    """What stays fixed while LM iterates over one edge set: local edges, their points and poses
    (where the blocks of the Schur complement's point-major matrices go), groupings, work arrays."""

    loc: np.ndarray          # indices of edges whose pose is optimised
    by_point: _Groups        # all edges by point
    loc_by_pose: _Groups     # local edges by pose
    loc_by_point: _Groups    # local edges by point
    loc_point: np.ndarray    # point and pose of every local edge
    loc_pose: np.ndarray
    n_points: int
    n_local: int
    unique: bool             # no point seen twice by one local pose (then a scatter needs no sums)
    work: _Work              # this call's work arrays
    by_pose: _ByPose         # all edges by pose
    loc_by_pose_index: np.ndarray   # where the local edges are in by_pose's order
    flat: np.ndarray | None = None    # unique: where (edge, j, k) of a (m,6,3) block goes in point_major

    @staticmethod
    def build(edges: StereoEdges, n_local: int, n_points: int, work: _Work) -> "_Structure":
        loc = np.flatnonzero(edges.pose < n_local)
        pts, kf = edges.point[loc], edges.pose[loc]
        # no (point, pose) key twice: one bincount over the P x L keys (np.unique sorted ~15 k keys per call)
        unique = len(loc) == 0 or int(np.bincount(pts * n_local + kf).max()) <= 1
        by_pose = _ByPose(edges)
        st = _Structure(loc, _Groups(edges.point, n_points), _Groups(kf, n_local), _Groups(pts, n_points),
                        pts, kf, n_points, n_local, unique, work, by_pose, by_pose.inverse[loc])
        if unique:
            # where element (edge, j, k) of an (m,6,3) block stack goes in the (n,3,L,6) point-major
            # matrix: ((p * 3 + k) * L + l) * 6 + j = (p * 3L + l) * 6 + (k * 6L + j)
            jk = np.arange(3)[None, :] * (6 * n_local) + np.arange(6)[:, None]
            st.flat = (((pts * (3 * n_local) + kf) * 6)[:, None] + jk.reshape(1, -1)).reshape(-1)
        return st

    def chunked_shape(self) -> tuple[int, int, int]:
        n = -(-self.n_points // POINTS_PER_CHUNK) * POINTS_PER_CHUNK
        return n // POINTS_PER_CHUNK, 3 * POINTS_PER_CHUNK, 6 * self.n_local

    def point_major(self, blocks: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The (3 P, 6 L) matrix whose (point, pose) 3x6 block is the transpose of the local edge's
        (6,3) block, zero where the pose does not see the point (blocks of one point and pose
        summed), cut into chunks of ``POINTS_PER_CHUNK`` points (padded with zero rows):
        (chunks, 3 POINTS_PER_CHUNK, 6 L). Products of the chunks stay below OpenBLAS's
        threading threshold: one (6L x 3P) GEMM goes multi-threaded, and its spinning threads
        cost 100+ ms of CPU per call on a loaded 2-core machine (1 ms single-threaded).
        ``out``, unique structures only: a zeroed array of that shape (or one this structure's blocks
        went into), written by one flat scatter (a fresh zeroed matrix and ``out[pts, :, kf] =
        blocks.transpose(0, 2, 1)`` cost ~2x more per KITTI linearisation, issue 8)."""
        if out is not None:
            out.reshape(-1)[self.flat] = np.ascontiguousarray(blocks).reshape(-1)
            return out
        shape = self.chunked_shape()
        out = np.zeros((shape[0] * POINTS_PER_CHUNK, 3, self.n_local, 6))
        np.add.at(out, (self.loc_point, slice(None), self.loc_pose), blocks.transpose(0, 2, 1))
        return out.reshape(shape)


def _mv(M: np.ndarray, v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Batched matrix-vector product (matmul on stacks of small matrices beats einsum ~10x).
    ``np.matvec`` (numpy >= 2.2) is the same gufunc loop as ``(M @ v[..., None])[..., 0]``, bit for
    bit, without the trailing unit axis (issue 8: ~25 % less per call on KITTI's ~7 k edges)."""
    return _MATVEC(M, v, out=out)


def _matvec_by_matmul(M: np.ndarray, v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    if out is None:
        return (M @ v[..., None])[..., 0]
    np.matmul(M, v[..., None], out=out[..., None])
    return out


_MATVEC = getattr(np, "matvec", _matvec_by_matmul)
