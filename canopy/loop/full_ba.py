"""Full bundle adjustment after a loop (AGRI §3.4.2; ORB-SLAM's global BA) and landmark
fusion across the loop (ORB-SLAM CorrectLoop's SearchAndFuse).

The pose graph moves keyframes as rigid blocks: the relative poses of the drifted map are
its measurements, so the error spread along the lap stays. A full bundle adjustment uses
every observation again (AGRI Eq. 9 stereo reprojection terms, Huber kernel, Eq. 11 summed
over all keyframes and map points) once the loop has brought the two ends of the lap
together, and it only pulls the lap together where the same tree is one map point at both
ends: ``fuse_across_loop`` finds those duplicates (the candidate side's landmarks projected
into the query side's keyframes and matched by descriptor) so the BA sees them as one.

Everything here works on the loop closer's own copy of the map (``PlaceKeyframe`` rows and
landmark positions sent by local mapping); local mapping applies the result
(``apply_global_ba``) as it applies a pose-graph correction.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import as_words, match_in_window
from canopy.loop.keyframe import PlaceKeyframe
from canopy.loop.params import LoopParams
from shared.arrays import unique_sorted
from shared.types import StereoCalibration

X = gtsam.symbol_shorthand.X
L = gtsam.symbol_shorthand.L


def resolve(lid: int, alias: dict[int, int]) -> int:
    """The landmark ``lid`` stands for after fusions (alias chains followed to their end)."""
    seen = 0
    while lid in alias and seen < 64:
        lid = alias[lid]
        seen += 1
    return lid


def resolve_array(ids: np.ndarray, alias: dict[int, int]) -> np.ndarray:
    ids = np.asarray(ids, np.int64)
    if not alias or not len(ids):
        return ids
    return np.array([resolve(int(i), alias) if i >= 0 else -1 for i in ids.tolist()], np.int64)


@dataclass
class GlobalBAResult:
    poses: dict[int, np.ndarray]          # optimised T_world_cam of every keyframe in the BA
    corrections: dict[int, np.ndarray]    # C_k = T'_k T_k^-1 against the poses it started from
    landmark_ids: np.ndarray              # (M,) landmarks optimised
    positions: np.ndarray                 # (M,3) their optimised positions
    n_edges: int
    n_outliers: int
    initial_error: float
    final_error: float
    timings_ms: dict = field(default_factory=dict)
    # pixel noise (px, level 0) of the outlier test and the last pass's noise model: the assumed
    # ``LoopParams.pixel_sigma``, or the one estimated from the first pass (``full_ba_estimate_noise``)
    pixel_sigma: float = 1.0


def _observations(keyframes: dict[int, PlaceKeyframe], poses: dict[int, np.ndarray], positions: dict[int, np.ndarray],
                  alias: dict[int, int], min_observations: int, bearing_only_landmarks: bool = True):
    """All (keyframe, landmark, keypoint) edges of landmarks with a position, seen by at least
    ``min_observations`` keyframes (one view constrains no pose), one edge per keyframe and landmark;
    without ``bearing_only_landmarks``, only landmarks at least one keyframe measured in stereo."""
    e_kf, e_lm, e_kp, e_st = [], [], [], []
    for k in sorted(poses):
        kf = keyframes.get(k)
        if kf is None:
            continue
        lids = resolve_array(kf.landmark_ids, alias)
        rows = np.flatnonzero(lids >= 0)
        if not len(rows):
            continue
        # one observation per landmark in a keyframe (a fusion can leave two rows on one landmark)
        _, first = np.unique(lids[rows], return_index=True)
        rows = rows[np.sort(first)]
        e_kf.append(np.full(len(rows), k, np.int64))
        e_lm.append(lids[rows])
        e_kp.append(rows)
        e_st.append(np.asarray(kf.u_right, float)[rows] >= 0)
    if not e_kf:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    e_kf, e_lm, e_kp, e_st = np.concatenate(e_kf), np.concatenate(e_lm), np.concatenate(e_kp), np.concatenate(e_st)
    has_pos = np.array([int(l) in positions for l in e_lm.tolist()], bool)
    e_kf, e_lm, e_kp, e_st = e_kf[has_pos], e_lm[has_pos], e_kp[has_pos], e_st[has_pos]
    uniq, inv, counts = np.unique(e_lm, return_inverse=True, return_counts=True)
    keep = counts[inv] >= min_observations
    if not bearing_only_landmarks:  # a landmark with no stereo edge has no measured depth
        keep &= np.bincount(inv, weights=e_st.astype(float), minlength=len(uniq))[inv] > 0
    return e_kf[keep], e_lm[keep], e_kp[keep]


def _edge_residuals(poses: dict, pos: dict, e_kf, e_lm, uv, ur, stereo, calib: StereoCalibration):
    """Per-axis reprojection residuals (n,3) of every edge, (u, v, u_right) in pixels (AGRI Eq. 9;
    u_right NaN on monocular edges), and whether the point is in front of the camera."""
    kfs, kf_inv = np.unique(e_kf, return_inverse=True)
    T_cw = np.stack([se3_inv(poses[k]) for k in kfs.tolist()])
    P = np.array([pos[l] for l in e_lm.tolist()], float).reshape(-1, 3)
    Pc = np.einsum("nij,nj->ni", T_cw[kf_inv, :3, :3], P) + T_cw[kf_inv, :3, 3]
    z = Pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = calib.fx * Pc[:, 0] / z + calib.cx
        v = calib.fy * Pc[:, 1] / z + calib.cy
        urp = u - calib.fx * calib.baseline / z
    res = np.stack([uv[:, 0] - u, uv[:, 1] - v, np.where(stereo, ur - urp, np.nan)], axis=1)
    return res, z > 1e-3


def estimate_pixel_noise(residuals: np.ndarray, octave: np.ndarray, scale_factor: float,
                         inliers: np.ndarray, n_parameters: int = 0) -> float:
    """Pixel noise (px at pyramid level 0) from the per-axis reprojection residuals of the inlier
    edges after a BA pass: 1.4826 * MAD (the median absolute deviation is a consistent estimator of
    a Gaussian's sigma that ignores the remaining outliers; Rousseeuw & Croux 1993). Each residual is
    first divided by its level's scale (ORB-SLAM's sigma = scale_factor^octave). The residuals of a
    fitted model are smaller than the noise: with m residuals and ``n_parameters`` fitted, the
    estimate is scaled by sqrt(m / (m - n_parameters)) (the degrees-of-freedom correction of the
    residual variance; a landmark seen twice absorbs half its noise). NaN if no residual."""
    r = np.asarray(residuals, float)[inliers] / (scale_factor ** np.asarray(octave, float)[inliers])[:, None]
    r = r[np.isfinite(r)]
    if not len(r) or len(r) <= n_parameters:
        return float("nan")
    mad = 1.4826 * np.median(np.abs(r - np.median(r)))
    return float(mad * np.sqrt(len(r) / (len(r) - n_parameters)))


def global_bundle_adjust(keyframes: dict[int, PlaceKeyframe], poses: dict[int, np.ndarray],
                         positions: dict[int, np.ndarray], calib: StereoCalibration, params: LoopParams,
                         alias: dict[int, int] | None = None, fixed: int | None = None,
                         on_iteration=None) -> GlobalBAResult:
    """Bundle adjustment of every keyframe in ``poses`` and every landmark they observe
    (AGRI Eq. 11 point terms with stereo factors and a Huber kernel, ORB-SLAM GlobalBundleAdjustment):
    a robust pass, observations beyond the chi2 bound dropped, a second pass. The oldest keyframe
    holds the gauge. ``on_iteration()`` is called between Levenberg-Marquardt iterations (the
    actor's heartbeat)."""
    t0 = time.perf_counter()
    alias = alias or {}
    fixed = min(poses) if fixed is None else fixed
    e_kf, e_lm, e_kp = _observations(keyframes, poses, positions, alias, params.full_ba_min_observations,
                                     params.full_ba_bearing_only_landmarks)
    n = len(e_kf)
    uv = np.empty((n, 2))
    ur = np.empty(n)
    octv = np.empty(n, np.int64)
    for k in unique_sorted(e_kf).tolist():
        m = e_kf == k
        kf = keyframes[k]
        uv[m] = np.asarray(kf.uv, float)[e_kp[m]]
        ur[m] = np.asarray(kf.u_right, float)[e_kp[m]]
        octv[m] = np.asarray(kf.octave, np.int64)[e_kp[m]]
    stereo = ur >= 0
    # edges of landmarks no keyframe measured in stereo (LoopParams.full_ba_bearing_only_sigma_factor)
    _, lm_inv = np.unique(e_lm, return_inverse=True)
    bearing_lm = np.bincount(lm_inv, weights=stereo.astype(float))[lm_inv] == 0 if n else np.zeros(0, bool)
    edge_factor = np.where(bearing_lm, params.full_ba_bearing_only_sigma_factor, 1.0)
    level_scale = params.scale_factor ** octv.astype(float) * edge_factor
    pixel_sigma = float(params.pixel_sigma)
    lm_ids = unique_sorted(e_lm)
    K = gtsam.Cal3_S2Stereo(calib.fx, calib.fy, 0.0, calib.cx, calib.cy, calib.baseline)
    Kmono = gtsam.Cal3_S2(calib.fx, calib.fy, 0.0, calib.cx, calib.cy)
    noise_cache: dict = {}

    def noise(is_stereo: bool, o: int, factor: float = 1.0):
        m = noise_cache.get((is_stereo, o, pixel_sigma, factor))
        if m is None:
            base = gtsam.noiseModel.Isotropic.Sigma(3 if is_stereo else 2, pixel_sigma * params.scale_factor**o * factor)
            hub = gtsam.noiseModel.mEstimator.Huber.Create(np.sqrt(params.chi2_stereo if is_stereo else params.chi2_mono))
            m = noise_cache[(is_stereo, o, pixel_sigma, factor)] = gtsam.noiseModel.Robust.Create(hub, base)
        return m

    kf_ids = sorted(set(unique_sorted(e_kf).tolist()) | {fixed})
    values = gtsam.Values()
    for k in kf_ids:
        values.insert(X(k), gtsam.Pose3(np.asarray(poses[k], float)))
    for lid in lm_ids.tolist():
        values.insert(L(lid), np.asarray(positions[lid], float))
    active = np.ones(n, bool)
    bound = np.where(stereo, params.chi2_stereo, params.chi2_mono)
    initial_error = final_error = 0.0
    t_build = 0.0
    for p in range(params.full_ba_passes):
        tb = time.perf_counter()
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorPose3(X(fixed), gtsam.Pose3(np.asarray(poses[fixed], float)),
                                         gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
        for j in np.flatnonzero(active).tolist():
            if stereo[j]:
                graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(uv[j, 0], ur[j], uv[j, 1]),
                                                      noise(True, int(octv[j])), X(int(e_kf[j])), L(int(e_lm[j])), K))
            else:
                graph.add(gtsam.GenericProjectionFactorCal3_S2(gtsam.Point2(uv[j, 0], uv[j, 1]),
                                                               noise(False, int(octv[j]), float(edge_factor[j])),
                                                               X(int(e_kf[j])),
                                                               L(int(e_lm[j])), Kmono))
        t_build += time.perf_counter() - tb
        lm_params = gtsam.LevenbergMarquardtParams()
        lm_params.setMaxIterations(params.full_ba_iterations)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params)
        if p == 0:
            initial_error = float(graph.error(values))
        prev = optimizer.error()
        for _ in range(params.full_ba_iterations):  # step by step: the actor stays alive between steps
            optimizer.iterate()
            if on_iteration is not None:
                on_iteration()
            err = optimizer.error()
            if prev - err <= 1e-5 * max(prev, 1e-12):
                break
            prev = err
        values = optimizer.values()
        final_error = float(graph.error(values))
        cur_poses = {k: values.atPose3(X(k)).matrix() for k in kf_ids}
        cur_pos = {lid: np.asarray(values.atPoint3(L(lid)), float) for lid in lm_ids.tolist()}
        res, front = _edge_residuals(cur_poses, cur_pos, e_kf, e_lm, uv, ur, stereo, calib)
        with np.errstate(invalid="ignore"):
            err2 = np.nansum(res**2, axis=1) / level_scale**2   # squared error in level-0 pixels
        err2[~front | ~np.isfinite(err2)] = np.inf
        sigma_changed = False
        if p == 0 and params.full_ba_estimate_noise:
            # the 1 px of ORB-SLAM's chi2 test is an assumption; generated and rectified real images
            # are sharper (day-loop: 0.35 px), and a test at 1 px keeps observations 3 sigma off that
            # then pull the second pass. Estimated on the edges that pass the assumed test.
            inl = active & (err2 / pixel_sigma**2 <= bound)
            n_par = 3 * len(unique_sorted(e_lm[inl])) + 6 * max(len(unique_sorted(e_kf[inl])) - 1, 0)
            if params.full_ba_bearing_only_sigma_factor != 1.0:  # the noise of the edges at pixel_sigma
                inl = inl & ~bearing_lm
            est = estimate_pixel_noise(res, octv, params.scale_factor, inl, n_par)
            if np.isfinite(est):
                est = float(np.clip(est, params.full_ba_noise_min_px, params.full_ba_noise_max_px))
                sigma_changed = abs(est - pixel_sigma) > 0.05 * pixel_sigma
                pixel_sigma = est
        bad = err2 / pixel_sigma**2 > bound
        newly = active & bad
        active &= ~bad
        if p + 1 >= params.full_ba_passes or not (newly.any() or sigma_changed):
            break
    out_poses = {k: values.atPose3(X(k)).matrix() for k in kf_ids}
    positions_out = np.array([values.atPoint3(L(l)) for l in lm_ids.tolist()], float).reshape(-1, 3)
    return GlobalBAResult(out_poses, {k: out_poses[k] @ se3_inv(np.asarray(poses[k], float)) for k in kf_ids},
                          lm_ids.astype(np.int64), positions_out, n, int((~active).sum()), initial_error, final_error,
                          {"build": t_build * 1e3, "total": (time.perf_counter() - t0) * 1e3}, pixel_sigma)


def run_ba_job(job: dict, on_iteration=None) -> GlobalBAResult:
    """``global_bundle_adjust`` of a ``LoopCloser.ba_job()`` snapshot."""
    return global_bundle_adjust(job["keyframes"], job["poses"], job["positions"], job["calib"], job["params"],
                                job["alias"], fixed=job["fixed"], on_iteration=on_iteration)


def ba_worker(conn, job: dict) -> None:
    """Entry of the full-BA child process of the loop closer: the result (or the error, as
    text) goes back through ``conn``; nothing else of the parent (its sockets) is touched."""
    try:
        conn.send(("ok", run_ba_job(job)))
    except Exception as exc:  # reported by the actor, which carries on without the BA
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()


def fuse_across_loop(keyframes: dict[int, PlaceKeyframe], poses: dict[int, np.ndarray],
                     positions: dict[int, np.ndarray], query_group: list[int], candidate_group: list[int],
                     calib: StereoCalibration, params: LoopParams, alias: dict[int, int]) -> dict[int, int]:
    """ORB-SLAM SearchAndFuse after the correction: every landmark seen by the candidate side
    of the loop is projected into each keyframe of the query side (poses already corrected)
    and matched by descriptor in a small window; a keypoint there that observes another
    landmark observes a duplicate of the same tree, which becomes the older landmark.
    Returns the new fusions {duplicate -> kept} (also added to ``alias``). Without
    ``params.fuse_bearing_only`` only keypoints measured in stereo take part on either side."""
    def usable(kf: PlaceKeyframe, lids: np.ndarray) -> np.ndarray:
        ok = lids >= 0
        if not params.fuse_bearing_only:
            ok &= np.asarray(kf.u_right, float) >= 0
        return ok

    # candidate-side landmarks with a descriptor: that of the keypoint in the keyframe that saw it first
    lm_desc: dict[int, np.ndarray] = {}
    for k in sorted(candidate_group):
        kf = keyframes.get(k)
        if kf is None:
            continue
        lids = resolve_array(kf.landmark_ids, alias)
        for i in np.flatnonzero(usable(kf, lids)).tolist():
            lid = int(lids[i])
            if lid not in lm_desc and lid in positions:
                lm_desc[lid] = kf.descriptors[i]
    if not lm_desc:
        return {}
    c_ids = np.array(sorted(lm_desc), np.int64)
    c_pos = np.array([positions[l] for l in c_ids.tolist()], float)
    c_words = as_words(np.array([lm_desc[l] for l in c_ids.tolist()], np.uint8))
    c_set = set(c_ids.tolist())
    fused: dict[int, int] = {}
    for k in sorted(query_group):
        kf = keyframes.get(k)
        if kf is None or k not in poses:
            continue
        T_cw = se3_inv(poses[k])
        Pc = c_pos @ T_cw[:3, :3].T + T_cw[:3, 3]
        z = np.where(Pc[:, 2] > 0.1, Pc[:, 2], np.nan)
        proj = np.stack([calib.fx * Pc[:, 0] / z + calib.cx, calib.fy * Pc[:, 1] / z + calib.cy], axis=1)
        in_view = (np.isfinite(proj).all(axis=1) & (proj[:, 0] >= 0) & (proj[:, 0] < calib.width)
                   & (proj[:, 1] >= 0) & (proj[:, 1] < calib.height))
        if not in_view.any():
            continue
        proj = np.where(in_view[:, None], proj, -1e6)
        qi, ri, _ = match_in_window(proj, c_words, np.full(len(c_ids), params.fuse_radius), np.asarray(kf.uv, float),
                                    as_words(kf.descriptors), params.fuse_max_hamming, params.match_ratio,
                                    q_mask=in_view)
        lids = resolve_array(kf.landmark_ids, alias)
        ok = usable(kf, lids)
        for a, r in zip(qi.tolist(), ri.tolist()):
            mine, theirs = int(lids[r]), int(c_ids[a])
            if not ok[r] or mine == theirs or mine in c_set:
                continue
            keep, drop = min(mine, theirs), max(mine, theirs)  # the older landmark stays
            if resolve(drop, alias) != drop or drop in fused:
                continue
            fused[drop] = keep
            alias[drop] = keep
    return fused
