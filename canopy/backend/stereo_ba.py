"""Local bundle adjustment of stereo / monocular point observations in numpy (AGRI Eq. 8-9,
ORB-SLAM's LocalBundleAdjustment), solved with the Schur complement on the camera poses.

Why not GTSAM here: a local window has few optimised poses (<= ``window_size``, 6 DoF each) and
thousands of 3-DoF landmarks. Eliminating the landmarks first (Triggs et al., "Bundle
Adjustment - A Modern Synthesis", 2000, §6.1; g2o's BlockSolver as ORB-SLAM uses it) leaves a
reduced camera system of at most 6 x window_size unknowns, and every other step is a batched
3x3 / 3x6 block operation over the edges. Built in numpy this costs a few ms per iteration,
where building one GTSAM factor per observation in Python and solving the full graph cost
~100 ms per keyframe on KITTI. GTSAM stays in use for the line terms
(``canopy.backend.local_ba``).

The model is the one ``local_ba`` builds in GTSAM: residuals (u_l, v, u_r) - projection
(u_r only for stereo observations), sigma = pixel_sigma * scale^octave, a Huber kernel on the
whitened residual norm, Levenberg-Marquardt with lambda * I damping (GTSAM's defaults:
lambda_0 = 1e-5, factor 10, relative decrease tolerance 1e-5). Fixed keyframes are constants
(GTSAM held them with a 1e-6 prior). Pose increments act on the left of T_cam_world
(``canopy.frontend.geometry`` convention).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy.frontend.geometry import se3_exp, stereo_point_jacobian
from shared.types import StereoCalibration

LAMBDA_INITIAL = 1e-5   # GTSAM LevenbergMarquardtParams defaults
LAMBDA_FACTOR = 10.0
LAMBDA_MAX = 1e5
RELATIVE_ERROR_TOL = 1e-5
_MIN_DEPTH = 1e-6
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


def _project(T_cw: np.ndarray, X: np.ndarray, edges: StereoEdges, calib: StereoCalibration):
    """Residuals (E,3), camera-frame points (E,3) and rotations (E,3,3) of every edge."""
    # np.take from contiguous copies of the few poses' blocks: the same values as
    # T_cw[edges.pose, :3, :3] (mixed fancy index and slices), ~10x faster over ~7 k edges
    R = np.take(np.ascontiguousarray(T_cw[:, :3, :3]), edges.pose, axis=0)
    Pc = _mv(R, np.take(X, edges.point, axis=0)) + np.take(np.ascontiguousarray(T_cw[:, :3, 3]), edges.pose, axis=0)
    z = Pc[:, 2]
    front = z > _MIN_DEPTH
    iz = np.where(front, 1.0 / np.where(front, z, 1.0), 0.0)
    u = calib.fx * Pc[:, 0] * iz + calib.cx
    v = calib.fy * Pc[:, 1] * iz + calib.cy
    ur = u - calib.bf * iz
    r = edges.meas - np.stack([u, v, ur], axis=1)
    r[:, 2] *= edges.stereo
    r[~front] = 0.0
    return r, Pc, R, front


def _robust_cost(r: np.ndarray, front: np.ndarray, edges: StereoEdges) -> tuple[float, np.ndarray]:
    """Huber cost of all edges and the IRLS weight of every edge (0 behind the camera)."""
    e = np.sqrt((r**2).sum(axis=1)) / edges.sigma
    k = edges.huber
    inside = e <= k
    cost = float(np.where(inside, 0.5 * e**2, k * e - 0.5 * k**2)[front].sum())
    w = np.where(inside, 1.0, k / np.maximum(e, 1e-12)) / edges.sigma**2
    return cost, np.where(front, w, 0.0)


def _jacobians(Pc: np.ndarray, R: np.ndarray, edges: StereoEdges, calib: StereoCalibration,
               loc: np.ndarray | None = None):
    """d(u,v,ur)/dxi (E,3,6) for a left perturbation of T_cam_world, and d(u,v,ur)/dX (E,3,3);
    with ``loc`` the pose Jacobians of those edges only (the fixed poses' are never used)."""
    Jp = stereo_point_jacobian(Pc, calib, _MIN_DEPTH)
    Jp[:, 2, :] *= edges.stereo[:, None]
    Jpl, Pcl = (Jp, Pc) if loc is None else (np.take(Jp, loc, axis=0), np.take(Pc, loc, axis=0))
    # dPc/dxi = [-[Pc]x | I]: row r of Jc is (Pc x Jp_r, Jp_r). Jp's rows have a zero each
    # (d u_l/dy = d v/dx = d u_r/dy = 0, ``stereo_point_jacobian``), so the cross products are
    # written out without those terms, on contiguous vectors (the full (m,3) column products on
    # strided views cost ~1 ms per linearisation on KITTI, these ~0.2 ms; a dropped term was an
    # exact zero, so the values are the same up to the sign of an exact zero)
    x, y, z = (np.ascontiguousarray(Pcl[:, i]) for i in range(3))
    j00, j02, j11, j12, j20, j22 = (np.ascontiguousarray(Jpl[:, r, c])
                                    for r, c in ((0, 0), (0, 2), (1, 1), (1, 2), (2, 0), (2, 2)))
    Jc = np.zeros((len(Pcl), 3, 6))
    Jc[:, :, 3:] = Jpl
    Jc[:, 0, 0] = j02 * y
    Jc[:, 0, 1] = j00 * z - j02 * x
    Jc[:, 0, 2] = -j00 * y
    Jc[:, 1, 0] = j11 * -z + j12 * y
    Jc[:, 1, 1] = -j12 * x
    Jc[:, 1, 2] = j11 * x
    Jc[:, 2, 0] = j22 * y
    Jc[:, 2, 1] = j20 * z - j22 * x
    Jc[:, 2, 2] = -j20 * y
    return Jc, Jp @ R


class _Groups:
    """Sums of per-item blocks by an integer key in [0, n), with the grouping computed once (the
    edges of a BA keep their poses and points through all iterations): a sort, then
    ``np.add.reduceat`` over contiguous runs. (Gathers along the first axis here and below use
    ``np.take``: the same values as fancy indexing, 2-4x faster on ~7 k small blocks.)"""

    def __init__(self, keys: np.ndarray, n: int):
        self.order = np.argsort(keys, kind="stable")
        ks = keys[self.order]
        self.starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]]) if len(ks) else np.zeros(0, np.int64)
        self.keys = ks[self.starts]
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
    (where the blocks of the Schur complement's point-major matrices go), groupings."""

    loc: np.ndarray          # indices of edges whose pose is optimised
    by_point: _Groups        # all edges by point
    loc_by_pose: _Groups     # local edges by pose
    loc_by_point: _Groups    # local edges by point
    loc_point: np.ndarray    # point and pose of every local edge
    loc_pose: np.ndarray
    n_points: int
    n_local: int
    unique: bool             # no point seen twice by one local pose (then a scatter needs no sums)

    @staticmethod
    def build(edges: StereoEdges, n_local: int, n_points: int) -> "_Structure":
        loc = np.flatnonzero(edges.pose < n_local)
        pts, kf = edges.point[loc], edges.pose[loc]
        # no (point, pose) key twice: one bincount over the P x L keys (np.unique sorted ~15 k keys per call)
        unique = len(loc) == 0 or int(np.bincount(pts * n_local + kf).max()) <= 1
        return _Structure(loc, _Groups(edges.point, n_points), _Groups(kf, n_local), _Groups(pts, n_points),
                          pts, kf, n_points, n_local, unique)

    def point_major(self, blocks: np.ndarray) -> np.ndarray:
        """The (3 P, 6 L) matrix whose (point, pose) 3x6 block is the transpose of the local edge's
        (6,3) block, zero where the pose does not see the point (blocks of one point and pose
        summed), cut into chunks of ``POINTS_PER_CHUNK`` points (padded with zero rows):
        (chunks, 3 POINTS_PER_CHUNK, 6 L). Products of the chunks stay below OpenBLAS's
        threading threshold: one (6L x 3P) GEMM goes multi-threaded, and its spinning threads
        cost 100+ ms of CPU per call on a loaded 2-core machine (1 ms single-threaded)."""
        n = -(-self.n_points // POINTS_PER_CHUNK) * POINTS_PER_CHUNK
        out = np.zeros((n, 3, self.n_local, 6))
        pts, kf = self.loc_point, self.loc_pose
        if self.unique:
            out[pts, :, kf] = blocks.transpose(0, 2, 1)
        else:
            np.add.at(out, (pts, slice(None), kf), blocks.transpose(0, 2, 1))
        return out.reshape(n // POINTS_PER_CHUNK, 3 * POINTS_PER_CHUNK, 6 * self.n_local)


def _mv(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Batched matrix-vector product (matmul on stacks of small matrices beats einsum ~10x).
    ``np.matvec`` (numpy >= 2.2) is the same gufunc loop as ``(M @ v[..., None])[..., 0]``, bit for
    bit, without the trailing unit axis (issue 8: ~25 % less per call on KITTI's ~7 k edges)."""
    return _MATVEC(M, v)


def _matvec_by_matmul(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (M @ v[..., None])[..., 0]


_MATVEC = getattr(np, "matvec", _matvec_by_matmul)


def _inv_sym3(H: np.ndarray, lam: float) -> np.ndarray:
    """Inverses of the symmetric 3x3 blocks ``H + lam I`` (P,3,3) by their adjugates (the point
    blocks of the Schur complement; ~8x cheaper than LAPACK's batched ``inv`` on 3x3 stacks).
    Raises LinAlgError where a block is singular, as ``np.linalg.inv`` does."""
    a, b, c = H[:, 0, 0] + lam, H[:, 0, 1], H[:, 0, 2]
    d, e, f = H[:, 1, 1] + lam, H[:, 1, 2], H[:, 2, 2] + lam
    A = d * f - e * e
    B = c * e - b * f
    C = b * e - c * d
    det = a * A + b * B + c * C
    if not np.all(np.isfinite(det) & (det != 0)):
        raise np.linalg.LinAlgError("singular point block in the Schur complement")
    out = np.empty_like(H)
    out[:, 0, 0] = A
    out[:, 0, 1] = out[:, 1, 0] = B
    out[:, 0, 2] = out[:, 2, 0] = C
    out[:, 1, 1] = a * f - c * c
    out[:, 1, 2] = out[:, 2, 1] = b * c - a * e
    out[:, 2, 2] = a * d - b * b
    out /= det[:, None, None]
    return out


_UPPER3 = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
GRAM_ROWS = 3072   # rows per GEMM in _pose_blocks: 6 x 6 x 3072 stays below OpenBLAS's threading threshold


def _point_blocks(Jx: np.ndarray, w: np.ndarray, Wr: np.ndarray, groups: "_Groups") -> tuple[np.ndarray, np.ndarray]:
    """Per point: H_pp = sum_e w_e Jx_e^T Jx_e (3x3) and b_p = sum_e Jx_e^T (w_e r_e) (Triggs et al.
    2000, §6.1: the point blocks of the normal equations). Computed from the Jacobians' nine
    components as contiguous vectors over the edges: the six distinct entries of the symmetric
    block and the three of b_p are 45 vector operations, where one batched 3x3 matmul per edge
    (a BLAS call each) cost ~4x more on KITTI's ~5 k edges (issue 8). Same sums, rounded differently."""
    J = np.ascontiguousarray(Jx.reshape(-1, 9).T)        # J[3k + i] = d(residual k)/d(X_i)
    Jw = J * w
    cols = np.empty((9, len(w)))
    for c, (i, j) in enumerate(_UPPER3):
        cols[c] = Jw[i] * J[j] + Jw[3 + i] * J[3 + j] + Jw[6 + i] * J[6 + j]
    Wrt = np.ascontiguousarray(Wr.T)
    for i in range(3):
        cols[6 + i] = J[i] * Wrt[0] + J[3 + i] * Wrt[1] + J[6 + i] * Wrt[2]
    sums = groups.sum(np.ascontiguousarray(cols.T))      # (P, 9)
    H = np.empty((len(sums), 3, 3))
    for c, (i, j) in enumerate(_UPPER3):
        H[:, i, j] = sums[:, c]
        H[:, j, i] = sums[:, c]
    return H, np.ascontiguousarray(sums[:, 6:])


def _pose_blocks(Jc: np.ndarray, wl: np.ndarray, Wr: np.ndarray, groups: "_Groups") -> tuple[np.ndarray, np.ndarray]:
    """Per local pose: H_cc = sum_e w_e Jc_e^T Jc_e (6x6) and b_c = sum_e Jc_e^T (w_e r_e), as one
    (6 x 3n)(3n x 6) GEMM and one GEMV over the pose's n edges stacked, in chunks of ``GRAM_ROWS``
    rows (a 6x3x6 matmul per edge and their sums cost ~1.5 ms per linearisation on KITTI; these
    ~0.2 ms). Same sums, rounded differently."""
    n = groups.n
    H, b = np.zeros((n, 6, 6)), np.zeros((n, 6))
    if not len(groups.starts):
        return H, b
    order = groups.order
    A = np.take(Jc, order, axis=0).reshape(-1, 6)
    Aw = np.take(Jc * wl, order, axis=0).reshape(-1, 6)
    rw = np.take(Wr, order, axis=0).reshape(-1)
    ends = np.r_[groups.starts[1:], len(order)]
    for key, a, e in zip(groups.keys.tolist(), (3 * groups.starts).tolist(), (3 * ends).tolist()):
        for c in range(a, e, GRAM_ROWS):
            d = min(c + GRAM_ROWS, e)
            H[key] += A[c:d].T @ Aw[c:d]
            b[key] += A[c:d].T @ rw[c:d]
    return H, b


class _Linearised:
    """Normal equations of one linearisation point, eliminated onto the local poses."""

    def __init__(self, T_cw, X, edges: StereoEdges, n_local: int, calib: StereoCalibration, st: _Structure,
                 projected: tuple | None = None):
        """``projected``: ``_project`` of this (T_cw, X) and its ``_robust_cost``, when LM has just
        computed them to accept the step."""
        if projected is None:
            r, Pc, R, front = _project(T_cw, X, edges, calib)
            projected = (r, Pc, R, front), _robust_cost(r, front, edges)
        (r, Pc, R, front), (self.cost, w) = projected
        self.projection = projected[0]
        loc = st.loc
        Jc, Jx = _jacobians(Pc, R, edges, calib, loc)                    # Jc: local edges only
        Wr = r * w[:, None]
        self.Hpp, self.bp = _point_blocks(Jx, w, Wr, st.by_point)
        JlT = Jc.transpose(0, 2, 1)
        wl = np.take(w, loc)[:, None, None]
        self.Hcc, self.bc = _pose_blocks(Jc, wl, np.take(Wr, loc, axis=0), st.loc_by_pose)
        self.Hcp = JlT @ (np.take(Jx, loc, axis=0) * wl)                  # (m,6,3)
        self.pts, self.kf = edges.point[loc], edges.pose[loc]
        self.n_local = n_local
        self.st = st
        self._W = None

    def _point_major_pair(self, Hpp_inv: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``point_major`` of H_cp and of A = H_cp Hpp^-1. W does not depend on the damping, so it is
        built once per linearisation (LM may solve several times at one point). Where no point is
        seen twice by one pose, V's block (point p, pose l) is Hpp^-1[p] W's: one batched (3x3)(3x6L)
        product per point instead of a second scatter into a zeroed matrix (Hpp^-1 is exactly
        symmetric, so the products and their order are A's; identical results on recorded KITTI BAs)."""
        st = self.st
        if self._W is None:
            self._W = st.point_major(self.Hcp)
        W = self._W
        if not st.unique:
            return W, st.point_major(A)
        n_chunks, rows, cols = W.shape
        Hinv = np.zeros((n_chunks * rows // 3, 3, 3))
        Hinv[: len(Hpp_inv)] = Hpp_inv
        V = np.matmul(Hinv, W.reshape(-1, 3, cols)).reshape(n_chunks, rows, cols)
        return W, V

    def solve(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Damped step: (n_local,6) pose increments and (P,3) point increments."""
        L, st = self.n_local, self.st
        Hpp_inv = _inv_sym3(self.Hpp, lam)
        A = self.Hcp @ np.take(Hpp_inv, self.pts, axis=0)              # (m,6,3) H_cp Hpp^-1
        # reduced camera system S = H_cc + lam I - sum over points of H_cp Hpp^-1 H_pc, the sum as
        # the (6L x 3P) (3P x 6L) product of the point-major matrices W = [H_pc] and
        # V = [Hpp^-1 H_pc] (zero where a pose does not see the point): a few dense products
        # instead of one 6x3x6 product per pair of edges on a point (KITTI: ~24 k pairs; the
        # reduction 14 -> ~2 ms per solve)
        W, V = self._point_major_pair(Hpp_inv, A)
        S = -np.matmul(W.transpose(0, 2, 1), V).sum(axis=0)
        S4 = S.reshape(L, 6, L, 6)
        idx = np.arange(L)
        S4[idx, :, idx, :] += self.Hcc + lam * np.eye(6)
        g = self.bc - st.loc_by_pose.sum(_mv(A, np.take(self.bp, self.pts, axis=0)))
        dc = np.linalg.solve(S, g.reshape(-1)).reshape(L, 6)
        rhs = self.bp - st.loc_by_point.sum(_mv(self.Hcp.transpose(0, 2, 1), np.take(dc, self.kf, axis=0)))
        return dc, _mv(Hpp_inv, rhs)


def edge_chi2(T_cw: np.ndarray, X: np.ndarray, edges: StereoEdges, calib: StereoCalibration,
              min_depth: float = _MIN_DEPTH) -> np.ndarray:
    """Squared reprojection error of every edge over sigma^2 (inf closer than ``min_depth``)."""
    r, Pc, _, _ = _project(T_cw, X, edges, calib)
    return projection_chi2(r, Pc, edges.sigma, min_depth)


def projection_chi2(r: np.ndarray, Pc: np.ndarray, sigma: np.ndarray, min_depth: float = _MIN_DEPTH) -> np.ndarray:
    """``edge_chi2`` from a projection already made (``_project``'s residuals and camera points)."""
    chi2 = (r**2).sum(axis=1) / sigma**2
    chi2[~(Pc[:, 2] > min_depth)] = np.inf
    return chi2


def _apply(T_cw: np.ndarray, X: np.ndarray, dc: np.ndarray, dp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    T_new = T_cw.copy()
    for k in range(len(dc)):
        T_new[k] = se3_exp(dc[k]) @ T_cw[k]
    return T_new, X + dp


def bundle_adjust_points(T_cw: np.ndarray, n_local: int, X: np.ndarray, edges: StereoEdges,
                         calib: StereoCalibration, max_iterations: int,
                         final_projection: list | None = None,
                         relative_tol: float = RELATIVE_ERROR_TOL) -> tuple[np.ndarray, np.ndarray, int]:
    """Levenberg-Marquardt on the local poses ``T_cw[:n_local]`` and all points ``X``; the poses
    ``T_cw[n_local:]`` stay fixed. Returns (T_cw, X, iterations).

    ``final_projection``: a list to which the residuals and camera-frame points of ``edges`` at
    the returned estimate are appended, ``(r, Pc)`` as ``_project`` gives them. LM has made that
    projection already (to accept its last step), so the caller's outlier test after BA
    (``projection_chi2``) needs no second one (issue 8: ~1 ms per KITTI BA call).
    ``relative_tol``: LM stops once an accepted step lowers the cost by less than this fraction."""
    T_cw = np.asarray(T_cw, float).copy()
    X = np.asarray(X, float).copy()
    if len(edges.pose) == 0:
        return T_cw, X, 0
    lam = LAMBDA_INITIAL
    st = _Structure.build(edges, n_local, len(X))
    lin = _Linearised(T_cw, X, edges, n_local, calib, st)
    current = lin.projection      # the projection at (T_cw, X)
    it = 0
    for it in range(1, max_iterations + 1):
        accepted = False
        while lam <= LAMBDA_MAX:
            try:
                dc, dp = lin.solve(lam)
            except np.linalg.LinAlgError:
                lam *= LAMBDA_FACTOR
                continue
            T_try, X_try = _apply(T_cw, X, dc, dp)
            proj = _project(T_try, X_try, edges, calib)
            robust = _robust_cost(proj[0], proj[3], edges)
            if robust[0] < lin.cost:
                accepted = True
                break
            lam *= LAMBDA_FACTOR
        if not accepted:
            break
        old = lin.cost
        T_cw, X = T_try, X_try
        current = proj
        lam = max(lam / LAMBDA_FACTOR, 1e-12)
        # converged or out of iterations: stop before linearising at the new point (its Jacobians
        # would be used by no further step)
        if old - robust[0] < relative_tol * old or it == max_iterations:
            break
        lin = _Linearised(T_cw, X, edges, n_local, calib, st, projected=(proj, robust))
    if final_projection is not None:
        final_projection.append(current[:2])
    return T_cw, X, it
