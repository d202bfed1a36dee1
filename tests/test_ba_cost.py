"""Local BA's cheaper Levenberg-Marquardt (issue 8, ``canopy.backend.stereo_ba``): the reorganised
products give the values of the per-edge definitions (bit for bit on this machine; to an ulp here), and the work arrays kept from one
BA call to the next change no result."""
from __future__ import annotations

import threading

import numpy as np

import canopy.backend.stereo_ba as sb
from canopy.backend.ba_layout import _ByPose
from canopy.frontend.geometry import project_stereo, se3_exp, stereo_point_jacobian
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal bytes: also the sign of every zero (the same code path on the same data)."""
    return a.shape == b.shape and a.tobytes() == b.tobytes()


def _equal_products(a: np.ndarray, b: np.ndarray) -> bool:
    """The reorganised product against numpy's per-edge one: equal to the last ulp or two. On this
    machine's OpenBLAS they are equal bit for bit (benchmarks/ab_mapping.py checks whole BA calls);
    another CPU's BLAS kernel may round a sum differently (FMA), which is not a wrong result."""
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-13, atol=1e-13 * max(1.0, float(np.abs(b).max()))))


def _window(rng, n_poses=6, n_local=4, n_points=90, per_point=(1, 4)):
    """A random window: poses near the origin looking at points 3-12 m ahead, each point seen by a
    few distinct poses, edges sorted by point (as local BA builds them); pose 5 sees one point only."""
    T = np.stack([se3_exp(np.r_[0.05 * rng.standard_normal(3), 0.5 * rng.standard_normal(3)]) for _ in range(n_poses)])
    X = np.stack([rng.uniform(-3, 3, n_points), rng.uniform(-2, 2, n_points), rng.uniform(3, 12, n_points)], axis=1)
    pose, point = [], []
    for p in range(n_points):
        seen = rng.choice(n_poses - 1, rng.integers(*per_point), replace=False)
        pose += sorted(seen.tolist())
        point += [p] * len(seen)
    pose.append(n_poses - 1)
    point.append(n_points - 1)
    pose, point = np.array(pose), np.array(point)
    order = np.argsort(point, kind="stable")
    pose, point = pose[order], point[order]
    meas = np.stack([project_stereo(T[k], X[p][None], CALIB)[0][0] for k, p in zip(pose, point)])
    E = len(pose)
    edges = sb.StereoEdges(pose, point, meas + rng.normal(0, 0.7, meas.shape), rng.random(E) < 0.7,
                           1.2 ** rng.integers(0, 4, E), np.full(E, 2.45))
    return T, X, edges, n_local


def test_point_jacobian_entries_and_rotation_are_the_per_edge_products():
    """``_jacobians``' d(u,v,ur)/dX is ``stereo_point_jacobian`` (u_r row times the stereo flag) times
    the pose's rotation per edge, bit for bit, with points behind the camera and mono edges; its
    pose Jacobian is the point Jacobian times dPc/dxi = [-[Pc]x | I]."""
    rng = np.random.default_rng(11)
    T, X, edges, n_local = _window(rng)
    st = sb._Structure.build(edges, n_local, len(X), sb._Work().begin())
    R = np.ascontiguousarray(T[:, :3, :3])
    Pc = np.stack([R[k] @ X[p] + T[k, :3, 3] for k, p in zip(edges.pose, edges.point)])
    Pc[::9, 2] = -0.5                                       # behind the camera: z clamped to min depth
    Jc, Jx = sb._jacobians(Pc, R, CALIB, st)
    Jp = stereo_point_jacobian(Pc, CALIB, sb._MIN_DEPTH)
    Jp[:, 2, :] *= edges.stereo[:, None]
    assert _equal_products(Jx, Jp @ np.take(R, edges.pose, axis=0))
    loc = st.loc
    x, y, z = Pc[loc].T
    dP = np.zeros((len(loc), 3, 6))
    dP[:, 0, 1], dP[:, 0, 2], dP[:, 1, 0], dP[:, 1, 2], dP[:, 2, 0], dP[:, 2, 1] = z, -y, -z, x, y, -x
    dP[:, :, 3:] = np.eye(3)
    np.testing.assert_allclose(Jc, Jp[loc] @ dP, rtol=1e-13, atol=1e-9)


def test_rotations_by_pose_equal_numpys_per_edge_products():
    """One GEMM per pose (``_ByPose``) gives what numpy's per-edge matvec / matmul give, bit for bit:
    poses with one edge, a few edges and many, in any order of the edges."""
    rng = np.random.default_rng(12)
    n_poses, E = 7, 700
    pose = np.r_[rng.choice(5, E - 3, p=[0.4, 0.3, 0.2, 0.07, 0.03]), 5, 6, 6]
    rng.shuffle(pose)
    point = rng.integers(0, 200, E)
    edges = sb.StereoEdges(pose, point, np.zeros((E, 3)), np.ones(E, bool), np.ones(E), np.ones(E))
    by_pose = _ByPose(edges)
    R = np.stack([se3_exp(np.r_[rng.standard_normal(3), 0, 0, 0])[:3, :3] for _ in range(n_poses)])
    X = rng.normal(0, 5, (200, 3))
    work = sb._Work().begin()
    out = by_pose.rotate(R, X, np.empty((E, 3)), work)
    assert _equal_products(out, np.matvec(np.take(R, pose, axis=0), np.take(X, point, axis=0)))
    Jp = rng.normal(0, 100, (E, 3, 3))
    Jp[:, 0, 1] = Jp[:, 1, 0] = Jp[:, 2, 1] = 0.0
    Jx = by_pose.rotate_jacobians(np.take(Jp, by_pose.order, axis=0), R, np.empty((E, 3, 3)), work)
    assert _equal_products(Jx, Jp @ np.take(R, pose, axis=0))


def test_schur_blocks_v_scattered_from_a_equal_the_per_point_product():
    """V's (point, pose) block Hpp^-1 W is A^T = (H_cp Hpp^-1)^T scattered (Hpp^-1 exactly symmetric),
    bit for bit; W and V are rewritten in place at every step without leftovers."""
    rng = np.random.default_rng(13)
    T, X, edges, n_local = _window(rng, n_points=75)         # 75 points: the last chunk is padded
    st = sb._Structure.build(edges, n_local, len(X), sb._Work().begin())
    assert st.unique
    for step in range(2):
        Hcp = rng.normal(size=(len(st.loc), 6, 3))
        H = rng.normal(size=(len(X), 3, 3))
        Hinv = sb._inv_sym3(H @ H.transpose(0, 2, 1), 1e-3)
        A = Hcp @ np.take(Hinv, st.loc_point, axis=0)
        W = st.point_major(Hcp, st.work.get("W", st.chunked_shape(), zero=True))
        V = st.point_major(A, st.work.get("V", st.chunked_shape(), zero=True))
        assert _same(W, st.point_major(Hcp))               # np.add.at into a fresh zeroed matrix
        n_chunks, rows, cols = W.shape
        Hpad = np.zeros((n_chunks * rows // 3, 3, 3))
        Hpad[: len(Hinv)] = Hinv
        assert _equal_products(V, np.matmul(Hpad, W.reshape(-1, 3, cols)).reshape(W.shape))


def test_work_arrays_kept_between_calls_change_no_result():
    """A BA call gives the same bytes whether this thread's work arrays are new or were used by a
    larger and a smaller window before; the final projection handed back is the caller's own (a
    later call does not overwrite it); a BA in another thread meanwhile changes nothing."""
    rng = np.random.default_rng(14)
    big, small = _window(rng, n_points=160), _window(rng, n_points=40)

    def run(w, final=None):
        T, X, edges, n_local = w
        return sb.bundle_adjust_points(T, n_local, X, edges, CALIB, 8, final_projection=final)

    fresh = {}

    def in_new_thread(name, w):
        fresh[name] = run(w, [])

    for name, w in (("big", big), ("small", small)):
        t = threading.Thread(target=in_new_thread, args=(name, w))
        t.start()
        t.join()
    final = []
    first = run(big, final)
    kept = [a.copy() for a in final[0]]
    other = threading.Thread(target=in_new_thread, args=("other", small))
    other.start()
    again = run(small), run(big)
    other.join()
    assert first[2] > 1
    for got, ref in ((first, fresh["big"]), (again[0], fresh["small"]), (again[1], fresh["big"]),
                     (fresh["other"], fresh["small"])):
        assert got[2] == ref[2] and _same(got[0], ref[0]) and _same(got[1], ref[1])
    assert all(_same(a, b) for a, b in zip(final[0], kept))
    np.testing.assert_array_equal(sb.projection_chi2(*final[0], big[2].sigma),
                                  sb.edge_chi2(first[0], first[1], big[2], CALIB))
