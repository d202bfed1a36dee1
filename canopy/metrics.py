"""Trajectory evaluation: association, alignment, APE/ATE, RPE, KITTI errors.

Pure numpy, no I/O and no plotting (evo's ``core/`` habit). The numbers
follow evo (github.com/MichaelGrupp/evo) so results can be compared with it
directly; ``tests/test_metrics.py`` reproduces evo's saved results on KITTI 00
to 10 decimals.

Conventions: poses are (N, 4, 4) ``T_world_cam``; ``est`` is the estimate and
``ref`` the reference (ground truth). Every statistics dict holds plain
Python floats (or ``None`` when there is nothing to measure) so it can go
straight to JSON.
"""
from __future__ import annotations

import numpy as np

from shared.types import Trajectory

# evo's relative tolerance for metre deltas in all-pairs mode (RPE rel_delta_tol).
RPE_REL_DELTA_TOL = 0.1
# KITTI devkit (evaluate_odometry.cpp): segment lengths in metres and frame step.
KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
KITTI_STEP_FRAMES = 10
# Fractions of the path used instead of KITTI_LENGTHS_M when the path is shorter
# than the first KITTI length (our sequences are often a few metres long).
KITTI_SHORT_PATH_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)

STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max", "sse")


# --------------------------------------------------------------------------- helpers

def _as_poses(poses, name: str) -> np.ndarray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape (N, 4, 4), got {p.shape}")
    return p


def _check_pair(est_poses, ref_poses) -> tuple[np.ndarray, np.ndarray]:
    est = _as_poses(est_poses, "est_poses")
    ref = _as_poses(ref_poses, "ref_poses")
    if len(est) != len(ref):
        raise ValueError(f"est has {len(est)} poses but ref has {len(ref)}; associate them first")
    return est, ref


def se3_inverse(poses: np.ndarray) -> np.ndarray:
    """Rigid inverse of (..., 4, 4) poses using R^T (as evo's lie.se3_inverse)."""
    poses = np.asarray(poses, dtype=np.float64)
    inv = np.zeros_like(poses)
    rt = np.swapaxes(poses[..., :3, :3], -1, -2)
    inv[..., :3, :3] = rt
    inv[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, poses[..., :3, 3])
    inv[..., 3, 3] = 1.0
    return inv


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle (rad) of (..., 3, 3) rotations, accurate for small and large angles.

    Uses atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2) instead of arccos, which
    loses precision near zero.
    """
    R = np.asarray(R, dtype=np.float64)
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                  R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    s = np.linalg.norm(v, axis=-1) / 2.0
    return np.arctan2(s, c)


def error_statistics(errors) -> dict:
    """evo's PE.get_all_statistics plus the count ``n``; all None when empty."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if e.size == 0:
        out = {k: None for k in STAT_KEYS}
        out["n"] = 0
        return out
    sq = e ** 2
    return {
        "rmse": float(np.sqrt(np.mean(sq))),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(sq)),
        "n": int(e.size),
    }


# --------------------------------------------------------------------------- association

def associate(stamps_a, stamps_b, max_diff: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Match two stamp lists by nearest time, one to one.

    As evo's ``sync.associate_trajectories``: every stamp of the shorter list
    is matched to the nearest stamp of the longer one and kept when
    ``|dt| <= max_diff``. Unlike evo's plain ``argmin`` this is strictly one to
    one: when several stamps pick the same partner, only the closest pair is
    kept (ties: the earlier stamp). Returns integer index arrays
    ``(idx_a, idx_b)`` ordered by the shorter list's index.
    """
    a = np.asarray(stamps_a, dtype=np.float64).reshape(-1)
    b = np.asarray(stamps_b, dtype=np.float64).reshape(-1)
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if a.size == 0 or b.size == 0:
        return empty
    b_longer = b.size > a.size
    short, long_ = (a, b) if b_longer else (b, a)

    order = np.argsort(long_, kind="stable")
    sorted_long = long_[order]
    pos = np.searchsorted(sorted_long, short)
    lo = np.clip(pos - 1, 0, sorted_long.size - 1)
    hi = np.clip(pos, 0, sorted_long.size - 1)
    d_lo = np.abs(short - sorted_long[lo])
    d_hi = np.abs(short - sorted_long[hi])
    pick = np.where(d_hi < d_lo, hi, lo)
    diff = np.minimum(d_lo, d_hi)
    idx_long = order[pick]
    idx_short = np.arange(short.size)

    keep = diff <= max_diff
    idx_short, idx_long, diff = idx_short[keep], idx_long[keep], diff[keep]
    # One to one: for every long index keep the closest short stamp.
    by_quality = np.lexsort((idx_short, diff))
    _, first = np.unique(idx_long[by_quality], return_index=True)
    chosen = np.sort(by_quality[first])
    idx_short, idx_long = idx_short[chosen].astype(np.int64), idx_long[chosen].astype(np.int64)
    return (idx_long, idx_short) if not b_longer else (idx_short, idx_long)


# --------------------------------------------------------------------------- alignment

def umeyama_alignment(X, Y, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares (R, t, s) with ``Y ~= s R X + t`` (Umeyama 1991).

    ``X`` and ``Y`` are (3, N) point sets with corresponding columns. Same
    formulas as evo's ``geometry.umeyama_alignment``; ``s`` is 1 unless
    ``with_scale``.
    """
    X = np.asarray(X, dtype=np.float64)
    Y = np.asarray(Y, dtype=np.float64)
    if X.shape != Y.shape or X.ndim != 2:
        raise ValueError(f"X and Y must both be (m, N), got {X.shape} and {Y.shape}")
    m, n = X.shape
    if n < 1:
        raise ValueError("umeyama_alignment needs at least one point pair")
    mean_x = X.mean(axis=1)
    mean_y = Y.mean(axis=1)
    xc = X - mean_x[:, None]
    yc = Y - mean_y[:, None]
    sigma_x = float(np.sum(xc ** 2)) / n
    cov_xy = yc @ xc.T / n
    u, d, vt = np.linalg.svd(cov_xy)
    S = np.eye(m)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        S[m - 1, m - 1] = -1.0
    R = u @ S @ vt
    if with_scale:
        if sigma_x == 0.0:
            raise ValueError("cannot estimate a scale: all points of X coincide")
        s = float(np.trace(np.diag(d) @ S) / sigma_x)
    else:
        s = 1.0
    t = mean_y - s * R @ mean_x
    return R, t, s


def align_trajectory(est_poses, ref_poses, with_scale: bool = False) -> np.ndarray:
    """Est poses aligned to ref by Umeyama on the positions, shape (N, 4, 4).

    As evo's ``PosePath3D.align``: scale the translations by ``s`` first,
    then left-multiply by ``[R t; 0 1]``.
    """
    est, ref = _check_pair(est_poses, ref_poses)
    R, t, s = umeyama_alignment(est[:, :3, 3].T, ref[:, :3, 3].T, with_scale)
    out = est.copy()
    out[:, :3, 3] *= s
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return np.einsum("ij,njk->nik", T, out)


# --------------------------------------------------------------------------- APE / RPE

def ape(est_poses, ref_poses, align: str = "se3") -> dict:
    """Absolute pose error, translation part (evo_ape ... --pose_relation trans_part).

    ``align``: "se3" (evo ``-a``), "sim3" (evo ``-as``) or "none".
    Returns rmse, mean, median, std, min, max, sse (metres) and n.
    """
    est, ref = _check_pair(est_poses, ref_poses)
    if align == "se3" or align == "sim3":
        if len(est) > 0:
            est = align_trajectory(est, ref, with_scale=(align == "sim3"))
    elif align != "none":
        raise ValueError(f"align must be 'se3', 'sim3' or 'none', got {align!r}")
    return error_statistics(np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1))


def ate_sim3(est_poses, ref_poses) -> dict:
    """APE after a Sim(3) alignment (evo ``-as``), with the scale that aligns them.

    For monocular runs, whose map has no metric scale: ``scale`` is the Umeyama factor
    s in ``ref ~= s R est + t`` (metres per map unit); comparing it over windows of a run
    shows the scale drift. ``None`` entries when fewer than 3 poses or no motion.
    """
    est, ref = _check_pair(est_poses, ref_poses)
    pos = est[:, :3, 3]
    if len(est) < 3 or float(np.sum((pos - pos.mean(axis=0)) ** 2)) == 0.0:
        out = error_statistics(np.zeros(0))
        out["scale"] = None
        return out
    _, _, s = umeyama_alignment(pos.T, ref[:, :3, 3].T, with_scale=True)
    out = ape(est, ref, align="sim3")
    out["scale"] = float(s)
    return out


def _pairs_by_index(n: int, delta: int, all_pairs: bool) -> np.ndarray:
    """evo filters.filter_pairs_by_index."""
    if all_pairs:
        i = np.arange(max(n - delta, 0))
        return np.stack([i, i + delta], axis=1)
    ids = np.arange(0, n, delta)
    return np.stack([ids[:-1], ids[1:]], axis=1)


def _pairs_by_path(positions: np.ndarray, delta: float, tol: float, all_pairs: bool) -> np.ndarray:
    """evo filters.filter_pairs_by_path (current evo, accumulated path length)."""
    n = len(positions)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    if all_pairs:
        dist = np.concatenate([[0.0], np.cumsum(steps)])
        pairs = []
        for i in range(n - 1):
            from_here = dist[i + 1:] - dist[i]
            k = int(np.argmin(np.abs(from_here - delta)))
            if abs(from_here[k] - delta) <= tol:
                pairs.append((i, k + i + 1))
        return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    # Consecutive pairs: the path accumulates from pose 0 and resets to 0 at
    # every selected index (evo's loop, kept sequential for exact float sums).
    ids = []
    current = 0.0
    for i, step in enumerate(steps, start=1):
        current += float(step)
        if current >= delta:
            ids.append(i)
            current = 0.0
    ids = np.asarray(ids, dtype=np.int64)
    return np.stack([ids[:-1], ids[1:]], axis=1) if ids.size > 1 else np.zeros((0, 2), np.int64)


def rpe_pairs(poses, delta=1, unit: str = "frames", all_pairs: bool = False,
              rel_delta_tol: float = RPE_REL_DELTA_TOL) -> np.ndarray:
    """Index pairs (K, 2) chosen as evo's ``filters.id_pairs_from_delta``."""
    p = _as_poses(poses, "poses")
    if unit == "frames":
        if float(delta) != int(delta) or int(delta) < 1:
            raise ValueError(f"delta in frames must be a positive integer, got {delta}")
        return _pairs_by_index(len(p), int(delta), all_pairs).astype(np.int64)
    if unit == "m":
        if delta <= 0:
            raise ValueError(f"delta in metres must be positive, got {delta}")
        return _pairs_by_path(p[:, :3, 3], float(delta), float(delta) * rel_delta_tol, all_pairs)
    raise ValueError(f"unit must be 'frames' or 'm', got {unit!r}")


def rpe(est_poses, ref_poses, delta=1, unit: str = "frames", all_pairs: bool = False,
        pairs_from_reference: bool = False) -> dict:
    """Relative pose error as evo_rpe (no alignment).

    E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j), Q reference, P estimate. Pairs come
    from :func:`rpe_pairs` on the estimate (evo's default) or on the
    reference with ``pairs_from_reference`` (evo ``--pairs_from_reference``).
    Returns the translation statistics (metres) under the evo names
    ``rmse, mean, ...`` and the rotation-angle statistics (degrees) as
    ``rot_rmse, rot_mean, ...``, plus ``n``.
    """
    est, ref = _check_pair(est_poses, ref_poses)
    pairs = rpe_pairs(ref if pairs_from_reference else est, delta, unit, all_pairs)
    i, j = pairs[:, 0], pairs[:, 1]
    q_rel = np.einsum("nij,njk->nik", se3_inverse(ref[i]), ref[j])
    p_rel = np.einsum("nij,njk->nik", se3_inverse(est[i]), est[j])
    E = np.einsum("nij,njk->nik", se3_inverse(q_rel), p_rel)
    out = error_statistics(np.linalg.norm(E[:, :3, 3], axis=1))
    rot = error_statistics(np.degrees(rotation_angle(E[:, :3, :3])))
    out.update({f"rot_{k}": rot[k] for k in STAT_KEYS})
    return out


# --------------------------------------------------------------------------- KITTI devkit

def _kitti_none(lengths_used=None) -> dict:
    return {"t_rel_percent": None, "r_rel_deg_per_100m": None,
            "lengths_used": None if lengths_used is None else [float(x) for x in lengths_used],
            "n_segments": 0}


def kitti_relative_errors(est_poses, ref_poses, lengths=None) -> dict:
    """KITTI odometry devkit errors (evaluate_odometry.cpp, calcSequenceErrors).

    For every first frame in steps of 10 frames and every length L, the last
    frame is the first one whose reference path distance exceeds L; the
    segment error is ``inv(inv(P_f) P_l) (inv(Q_f) Q_l)`` and contributes
    ``|t| / L`` and ``angle / L``. Averages over all segments give
    ``t_rel_percent`` (%) and ``r_rel_deg_per_100m`` (deg per 100 m).

    ``lengths=None`` uses the devkit lengths 100..800 m, except when the
    reference path is shorter than 100 m: then the lengths are 10 %, 20 %,
    ..., 80 % of the path length (the devkit would find no segment at all).
    When no segment fits, the values are ``None`` and ``n_segments`` is 0.
    """
    est, ref = _check_pair(est_poses, ref_poses)
    if len(ref) < 2:
        return _kitti_none()
    pos = ref[:, :3, 3]
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    total = float(dist[-1])
    if lengths is None:
        if total <= 0.0:
            return _kitti_none()
        if total < KITTI_LENGTHS_M[0]:
            lengths = [f * total for f in KITTI_SHORT_PATH_FRACTIONS]
        else:
            lengths = list(KITTI_LENGTHS_M)
    lengths = [float(x) for x in lengths]

    firsts, lasts, seg_len = [], [], []
    for first in range(0, len(ref), KITTI_STEP_FRAMES):
        for L in lengths:
            # devkit lastFrameFromSegmentLength: first i with dist[i] > dist[first] + L
            k = int(np.searchsorted(dist, dist[first] + L, side="right"))
            if k >= len(ref):
                continue
            firsts.append(first)
            lasts.append(k)
            seg_len.append(L)
    if not firsts:
        return _kitti_none(lengths)
    f, l, L = np.asarray(firsts), np.asarray(lasts), np.asarray(seg_len)
    d_gt = np.einsum("nij,njk->nik", np.linalg.inv(ref[f]), ref[l])
    d_est = np.einsum("nij,njk->nik", np.linalg.inv(est[f]), est[l])
    err = np.einsum("nij,njk->nik", np.linalg.inv(d_est), d_gt)
    # devkit rotationError: acos(clamp(0.5 * (tr - 1), -1, 1))
    r_err = np.arccos(np.clip(0.5 * (np.trace(err[:, :3, :3], axis1=1, axis2=2) - 1.0), -1.0, 1.0))
    t_err = np.linalg.norm(err[:, :3, 3], axis=1)
    return {
        "t_rel_percent": float(np.mean(t_err / L) * 100.0),
        "r_rel_deg_per_100m": float(np.degrees(np.mean(r_err / L)) * 100.0),
        "lengths_used": lengths,
        "n_segments": int(len(f)),
    }


# --------------------------------------------------------------------------- motion

def motion_summary(poses) -> dict:
    """How far a trajectory moved: for "the MAV sits still" drift checks.

    ``translation_m``: distance between first and last position;
    ``rotation_deg``: angle of the rotation between first and last pose;
    ``path_length_m``: summed step lengths; ``max_displacement_m``: largest
    distance of any position from the first one; ``n``: number of poses.
    """
    p = _as_poses(poses, "poses")
    if len(p) == 0:
        return {"translation_m": None, "rotation_deg": None, "path_length_m": None,
                "max_displacement_m": None, "n": 0}
    pos = p[:, :3, 3]
    rel = p[0, :3, :3].T @ p[-1, :3, :3]
    return {
        "translation_m": float(np.linalg.norm(pos[-1] - pos[0])),
        "rotation_deg": float(np.degrees(rotation_angle(rel))),
        "path_length_m": float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum()),
        "max_displacement_m": float(np.linalg.norm(pos - pos[0], axis=1).max()),
        "n": int(len(p)),
    }


KITTI_MIN_PATH_M = 10.0


def evaluate_trajectory(est: Trajectory, gt: Trajectory | None, max_diff: float = 0.01,
                        valid: np.ndarray | None = None) -> dict:
    """All run metrics in one JSON-ready dict.

    Keys: ``ate`` (APE, SE(3) aligned), ``ate_sim3`` (APE after a Sim(3) alignment, with its
    ``scale``: the figure for monocular runs), ``rpe_frame`` (delta 1 frame),
    ``rpe_metre`` (delta 1 m, ``None`` when no pair of poses is 1 m apart
    along the path), ``kitti``, ``n_matched``, ``est_motion``, ``gt_motion``.
    Without ground truth, or when no stamp matches within ``max_diff``
    seconds, the error entries are ``None`` and ``note`` says why. ``valid`` (bool per
    estimated pose) leaves poses out, e.g. a monocular run's frames before initialisation.
    """
    if valid is not None:
        valid = np.asarray(valid, bool).reshape(-1)
        if len(valid) != len(est):
            raise ValueError(f"valid has {len(valid)} entries for {len(est)} poses")
        est = Trajectory(est.stamps[valid], est.poses[valid], meta=dict(est.meta))
    out = {"ate": None, "ate_sim3": None, "rpe_frame": None, "rpe_metre": None, "kitti": None, "n_matched": 0,
           "max_diff_s": float(max_diff),
           "est_motion": motion_summary(est.poses), "gt_motion": None, "note": None}
    if gt is None:
        out["note"] = "no ground truth"
        return out
    out["gt_motion"] = motion_summary(gt.poses)
    ia, ib = associate(est.stamps, gt.stamps, max_diff)
    out["n_matched"] = int(len(ia))
    if len(ia) == 0:
        out["note"] = f"no estimated stamp is within {max_diff} s of a ground-truth stamp"
        return out
    e, g = est.poses[ia], gt.poses[ib]
    out["ate"] = ape(e, g, align="se3")
    out["ate_sim3"] = ate_sim3(e, g)
    out["rpe_frame"] = rpe(e, g, delta=1, unit="frames")
    pairs_m = rpe_pairs(e, 1.0, "m")
    out["rpe_metre"] = rpe(e, g, delta=1.0, unit="m") if len(pairs_m) else None
    # KITTI's drift figures only mean something over a real drive.
    if out["gt_motion"]["path_length_m"] >= KITTI_MIN_PATH_M:
        out["kitti"] = kitti_relative_errors(e, g)
    else:
        out["kitti"] = _kitti_none()
        out["kitti"]["note"] = f"ground-truth path shorter than {KITTI_MIN_PATH_M} m"
    return out
