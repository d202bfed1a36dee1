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

import numpy as np

# StereoEdges is this module's input type (local_ba builds it)
from canopy.backend.ba_layout import StereoEdges, _Groups, _mv, _Structure, _take, _Work, _work
from canopy.frontend.geometry import se3_exp
from canopy.backend.attitude_prior import AttitudePriors
from shared.types import StereoCalibration

LAMBDA_INITIAL = 1e-5   # GTSAM LevenbergMarquardtParams defaults
LAMBDA_FACTOR = 10.0
LAMBDA_MAX = 1e5
RELATIVE_ERROR_TOL = 1e-5
_MIN_DEPTH = 1e-6


def _project(T_cw: np.ndarray, X: np.ndarray, edges: StereoEdges, calib: StereoCalibration,
             st: "_Structure | None" = None, slot: int = 0):
    """Residuals (E,3) and camera-frame points (E,3) of every edge, the poses' rotations (n,3,3), and
    which edges have their point in front; with ``st`` in its work arrays of projection ``slot``
    (LM keeps the accepted projection in one slot and tries a step in the other)."""
    work = st.work if st is not None else _Work()
    E = len(edges.pose)
    R = np.ascontiguousarray(T_cw[:, :3, :3])
    Pc = work.get(f"Pc{slot}", (E, 3))
    if st is not None:
        st.by_pose.rotate(R, X, Pc, work)
    else:
        # np.take from contiguous copies of the few poses' blocks: the same values as
        # T_cw[edges.pose, :3, :3] (mixed fancy index and slices), ~10x faster over ~7 k edges
        _mv(np.take(R, edges.pose, axis=0), np.take(X, edges.point, axis=0), out=Pc)
    Pc += _take(np.ascontiguousarray(T_cw[:, :3, 3]), edges.pose, work.get("t_e", (E, 3)))
    z = Pc[:, 2]
    front = z > _MIN_DEPTH
    iz = np.where(front, 1.0 / np.where(front, z, 1.0), 0.0)
    u = calib.fx * Pc[:, 0] * iz + calib.cx
    v = calib.fy * Pc[:, 1] * iz + calib.cy
    ur = u - calib.bf * iz
    r = work.get(f"r{slot}", (E, 3))
    for c, pred in enumerate((u, v, ur)):
        np.subtract(edges.meas[:, c], pred, out=r[:, c])
    r[:, 2] *= edges.stereo
    r[~front] = 0.0
    return r, Pc, R, front


def _robust_cost(r: np.ndarray, front: np.ndarray, edges: StereoEdges) -> tuple[float, np.ndarray]:
    """Huber cost of all edges and the IRLS weight of every edge (0 behind the camera)."""
    # the squared norm summed over the columns as (r0^2 + r1^2) + r2^2, the order numpy's row sum
    # of three takes, on contiguous columns: the same values at ~1/5 of the cost (issue 8)
    rt = np.ascontiguousarray(r.T)
    e = np.sqrt(rt[0] * rt[0] + rt[1] * rt[1] + rt[2] * rt[2]) / edges.sigma
    k = edges.huber
    inside = e <= k
    cost = float(np.where(inside, 0.5 * e**2, k * e - 0.5 * k**2)[front].sum())
    w = np.where(inside, 1.0, k / np.maximum(e, 1e-12)) / edges.sigma**2
    return cost, np.where(front, w, 0.0)


def _jacobians(Pc: np.ndarray, R: np.ndarray, calib: StereoCalibration, st: "_Structure") -> tuple[np.ndarray, np.ndarray]:
    """d(u,v,ur)/dxi (m,3,6) of the local edges ``st.loc`` for a left perturbation of T_cam_world,
    and d(u,v,ur)/dX (E,3,3) of all edges; ``R``: the poses' rotations (n,3,3)."""
    # the six non-zero entries of ``stereo_point_jacobian(Pc, calib, _MIN_DEPTH)`` by its expressions
    # (the u_r row times the stereo flag), as vectors in the edges' pose order, written into an
    # (E,3,3) array zeroed once per call (tests/test_ba_cost.py: the same bytes)
    by_pose, work, loc = st.by_pose, st.work, st.loc
    Ps = _take(Pc, by_pose.order, work.get("Pc_by_pose", Pc.shape))
    x, y = Ps[:, 0], Ps[:, 1]
    iz = 1.0 / np.maximum(Ps[:, 2], _MIN_DEPTH)
    iz2 = iz * iz
    stereo = by_pose.stereo
    comps = (calib.fx * iz, -calib.fx * x * iz2, calib.fy * iz, -calib.fy * y * iz2,
             calib.fx * iz * stereo, -calib.fx * (x - calib.baseline) * iz2 * stereo)
    Jp = work.get("Jp_by_pose", (len(Pc), 3, 3), zero=True)
    for (r, c), v in zip(_JP_ENTRIES, comps):
        Jp[:, r, c] = v
    Jx = by_pose.rotate_jacobians(Jp, R, work.get("Jx", Jp.shape), work)
    # dPc/dxi = [-[Pc]x | I]: row r of Jc is (Pc x Jp_r, Jp_r), written out without the terms of
    # Jp's zeros (d u_l/dy = d v/dx = d u_r/dy = 0) on contiguous vectors
    x, y, z = (np.take(Pc[:, i], loc) for i in range(3))
    j00, j02, j11, j12, j20, j22 = (np.take(v, st.loc_by_pose_index) for v in comps)
    Jc = work.get("Jc", (len(loc), 3, 6), zero=True)    # its zeros: d(u_l)/dy, d(v)/dx, d(u_r)/dy
    for (r, c), v in zip(_JP_ENTRIES, (j00, j02, j11, j12, j20, j22)):
        Jc[:, r, 3 + c] = v
    Jc[:, 0, 0] = j02 * y
    Jc[:, 0, 1] = j00 * z - j02 * x
    Jc[:, 0, 2] = -j00 * y
    Jc[:, 1, 0] = j11 * -z + j12 * y
    Jc[:, 1, 1] = -j12 * x
    Jc[:, 1, 2] = j11 * x
    Jc[:, 2, 0] = j22 * y
    Jc[:, 2, 1] = j20 * z - j22 * x
    Jc[:, 2, 2] = -j20 * y
    return Jc, Jx


_JP_ENTRIES = ((0, 0), (0, 2), (1, 1), (1, 2), (2, 0), (2, 2))   # the non-zero entries of d(u,v,ur)/dPc


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


def _point_blocks(Jx: np.ndarray, w: np.ndarray, Wr: np.ndarray, groups: "_Groups",
                  work: _Work | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per point: H_pp = sum_e w_e Jx_e^T Jx_e (3x3) and b_p = sum_e Jx_e^T (w_e r_e) (Triggs et al.
    2000, §6.1: the point blocks of the normal equations). Computed from the Jacobians' nine
    components as contiguous vectors over the edges: the six distinct entries of the symmetric
    block and the three of b_p are 45 vector operations, where one batched 3x3 matmul per edge
    (a BLAS call each) cost ~4x more on KITTI's ~5 k edges (issue 8). Same sums, rounded differently."""
    E, work = len(w), work or _Work()
    J = work.get("J", (9, E))                             # J[3k + i] = d(residual k)/d(X_i)
    np.copyto(J, Jx.reshape(-1, 9).T)
    Jw = np.multiply(J, w, out=work.get("Jw", (9, E)))
    cols = work.get("cols", (9, E))
    for c, (i, j) in enumerate(_UPPER3):
        cols[c] = Jw[i] * J[j] + Jw[3 + i] * J[3 + j] + Jw[6 + i] * J[6 + j]
    Wrt = np.ascontiguousarray(Wr.T)
    for i in range(3):
        cols[6 + i] = J[i] * Wrt[0] + J[3 + i] * Wrt[1] + J[6 + i] * Wrt[2]
    colsT = work.get("colsT", (E, 9))
    np.copyto(colsT, cols.T)
    sums = groups.sum(colsT)                              # (P, 9)
    H = np.empty((len(sums), 3, 3))
    for c, (i, j) in enumerate(_UPPER3):
        H[:, i, j] = sums[:, c]
        H[:, j, i] = sums[:, c]
    return H, np.ascontiguousarray(sums[:, 6:])


def _pose_blocks(Jc: np.ndarray, wl: np.ndarray, Wr: np.ndarray, groups: "_Groups",
                 work: _Work | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per local pose: H_cc = sum_e w_e Jc_e^T Jc_e (6x6) and b_c = sum_e Jc_e^T (w_e r_e), as one
    (6 x 3n)(3n x 6) GEMM and one GEMV over the pose's n edges stacked, in chunks of ``GRAM_ROWS``
    rows (a 6x3x6 matmul per edge and their sums cost ~1.5 ms per linearisation on KITTI; these
    ~0.2 ms). Same sums, rounded differently."""
    n = groups.n
    H, b = np.zeros((n, 6, 6)), np.zeros((n, 6))
    if not len(groups.starts):
        return H, b
    order = groups.order
    m, work = len(order), work or _Work()
    A = _take(Jc, order, work.get("Jc_by_pose", Jc.shape))
    # the weights on the gathered rows, as an (m,18) x (m,1) product: the same products as
    # ``take(Jc * wl)``, whose (m,3,6) x (m,1,1) broadcast runs numpy's inner loop over 6 elements
    # at a time (issue 8)
    Aw = np.multiply(A.reshape(m, -1), np.take(wl.reshape(-1), order)[:, None],
                     out=work.get("Jcw_by_pose", (m, 18))).reshape(-1, 6)
    A = A.reshape(-1, 6)
    rw = np.take(Wr, order, axis=0).reshape(-1)
    for key, a, e in zip(groups.keys.tolist(), (3 * groups.starts).tolist(), (3 * groups.ends).tolist()):
        for c in range(a, e, GRAM_ROWS):
            d = min(c + GRAM_ROWS, e)
            H[key] += A[c:d].T @ Aw[c:d]
            b[key] += A[c:d].T @ rw[c:d]
    return H, b


class _Linearised:
    """Normal equations of one linearisation point, eliminated onto the local poses."""

    def __init__(self, T_cw, X, edges: StereoEdges, n_local: int, calib: StereoCalibration, st: _Structure,
                 projected: tuple | None = None, attitude: "AttitudePriors | None" = None):
        """``projected``: ``_project`` of this (T_cw, X) and its ``_robust_cost``, when LM has just
        computed them to accept the step. ``attitude``: pose-only prior terms
        (``canopy.backend.attitude_prior``), added to the cost and the poses' blocks."""
        if projected is None:
            r, Pc, R, front = _project(T_cw, X, edges, calib, st)
            projected = (r, Pc, R, front), _robust_cost(r, front, edges)
        (r, Pc, R, front), (self.cost, w) = projected
        self.projection = projected[0]
        loc, work = st.loc, st.work
        Jc, Jx = _jacobians(Pc, R, calib, st)                              # Jc: local edges only
        Wr = r * w[:, None]
        self.Hpp, self.bp = _point_blocks(Jx, w, Wr, st.by_point, work)
        JlT = Jc.transpose(0, 2, 1)
        wl = np.take(w, loc)[:, None, None]
        self.Hcc, self.bc = _pose_blocks(Jc, wl, np.take(Wr, loc, axis=0), st.loc_by_pose, work)
        if attitude is not None:
            self.cost += attitude.cost(T_cw)
            attitude.add_normal_blocks(T_cw, self.Hcc, self.bc)
        m = len(loc)
        Jxw = _take(Jx, loc, work.get("Jxw", (m, 3, 3)))
        np.multiply(Jxw.reshape(m, 9), wl.reshape(m, 1), out=Jxw.reshape(m, 9))  # = take(Jx, loc) * wl
        self.Hcp = np.matmul(JlT, Jxw, out=work.get("Hcp", (m, 6, 3)))     # (m,6,3)
        self.pts, self.kf = edges.point[loc], edges.pose[loc]
        self.n_local = n_local
        self.st = st
        self._W = None

    def _point_major_pair(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``point_major`` of H_cp (once per linearisation: LM may solve several times at one point)
        and of A = H_cp Hpp^-1. Where no point is seen twice by one pose, V's block (p, l) is A_e^T:
        Hpp^-1 is exactly symmetric (``_inv_sym3``), so A_e sums the products of Hpp^-1[p] H_pc,e in
        the same order (one FMA chain in OpenBLAS), bit for bit without a (3x3)(3x6L) BLAS call per
        point and a zero-padded copy of Hpp^-1."""
        st = self.st
        if not st.unique:
            if self._W is None:
                self._W = st.point_major(self.Hcp)
            return self._W, st.point_major(A)
        if self._W is None:
            self._W = st.point_major(self.Hcp, st.work.get("W", st.chunked_shape(), zero=True))
        return self._W, st.point_major(A, st.work.get("V", st.chunked_shape(), zero=True))

    def solve(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Damped step: (n_local,6) pose increments and (P,3) point increments."""
        L, st = self.n_local, self.st
        Hpp_inv = _inv_sym3(self.Hpp, lam)
        m = len(self.pts)
        A = np.matmul(self.Hcp, _take(Hpp_inv, self.pts, st.work.get("Hinv_e", (m, 3, 3))),
                      out=st.work.get("A", (m, 6, 3)))                     # (m,6,3) H_cp Hpp^-1
        # reduced camera system S = H_cc + lam I - sum over points of H_cp Hpp^-1 H_pc, the sum as
        # the (6L x 3P) (3P x 6L) product of the point-major matrices W = [H_pc] and
        # V = [Hpp^-1 H_pc] (zero where a pose does not see the point): a few dense products
        # instead of one 6x3x6 product per pair of edges on a point (KITTI: ~24 k pairs; the
        # reduction 14 -> ~2 ms per solve)
        W, V = self._point_major_pair(A)
        S = -np.matmul(W.transpose(0, 2, 1), V, out=st.work.get("S_chunks", (len(W),) + W.shape[2:] * 2)).sum(axis=0)
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
                         relative_tol: float = RELATIVE_ERROR_TOL,
                         attitude: "AttitudePriors | None" = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Levenberg-Marquardt on the local poses ``T_cw[:n_local]`` and all points ``X``; the poses
    ``T_cw[n_local:]`` stay fixed. Returns (T_cw, X, iterations).

    ``final_projection``: a list to which the residuals and camera-frame points of ``edges`` at
    the returned estimate are appended, ``(r, Pc)`` as ``_project`` gives them. LM has made that
    projection already (to accept its last step), so the caller's outlier test after BA
    (``projection_chi2``) needs no second one (issue 8: ~1 ms per KITTI BA call).
    ``relative_tol``: LM stops once an accepted step lowers the cost by less than this fraction.
    ``attitude``: prior terms on the local poses' pitch and roll (``canopy.backend.attitude_prior``)."""
    T_cw = np.asarray(T_cw, float).copy()
    X = np.asarray(X, float).copy()
    if len(edges.pose) == 0:
        return T_cw, X, 0
    lam = LAMBDA_INITIAL
    st = _Structure.build(edges, n_local, len(X), _work().begin())
    lin = _Linearised(T_cw, X, edges, n_local, calib, st, attitude=attitude)
    current = lin.projection      # the projection at (T_cw, X), in slot 0 of st.work
    slot = 1                      # where a step's projection goes
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
            proj = _project(T_try, X_try, edges, calib, st, slot)
            robust = _robust_cost(proj[0], proj[3], edges)
            total = robust[0] + (attitude.cost(T_try) if attitude is not None else 0.0)
            if total < lin.cost:
                accepted = True
                break
            lam *= LAMBDA_FACTOR
        if not accepted:
            break
        old = lin.cost
        T_cw, X = T_try, X_try
        current, slot = proj, 1 - slot
        lam = max(lam / LAMBDA_FACTOR, 1e-12)
        # converged or out of iterations: stop before linearising at the new point (its Jacobians
        # would be used by no further step)
        if old - total < relative_tol * old or it == max_iterations:
            break
        lin = _Linearised(T_cw, X, edges, n_local, calib, st, projected=(proj, robust), attitude=attitude)
    if final_projection is not None:
        final_projection.append(tuple(a.copy() for a in current[:2]))   # the next call reuses the arrays
    return T_cw, X, it
