"""A stereo rig's constant disparity offset from a whole map's bundle adjustment (no ground truth).

A rectified rig whose right principal point is off by ``delta`` measures every disparity ``delta`` short:
d_true = d_measured + delta (``canopy.frontend.disparity_offset`` explains why the error grows with depth and
why motion makes it observable). The two-frame estimator there sees each point from two frames one step
apart; a tracked map sees most points from several keyframes metres apart, and a far point's depth follows
from that motion better than from any one pair. So the map constrains the offset more tightly: an offset
that disagrees with the motion leaves residuals that no pose or point can absorb, because it bends depth by
a different fraction at every distance.

``map_offset_profile`` measures it as a profile likelihood: the map's bundle adjustment (every keyframe but
the first and every point free; ``canopy.backend.stereo_ba``'s Levenberg-Marquardt, the same residuals and
Huber kernels as local BA) converged with every stereo observation's right column shifted by ``-delta``,
over a grid of ``delta``. A parabola through the three lowest neighbouring costs gives the minimum; its
curvature and the residuals' own scale give a standard error (Gauss-Newton: var = s^2 / C'' with
s^2 = 2 C_min / n_residuals, C the Huber cost, quadratic near the minimum).

Measured (docs/notes/s30-offset.md): on the generated day-loop, whose rig is exact, the estimate is
-0.047 px (se 0.007; an offset of +0.2 px put into the tracker is found as +0.227 by one profile); on the
KITTI 06 snippet +0.100 px (se 0.013) for the cells extractor, where the two-frame estimator gives +0.151 +- 0.035.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy.backend.stereo_ba import StereoEdges, _project, _robust_cost, bundle_adjust_points, edge_chi2
from canopy.frontend.geometry import se3_inv
from shared.types import StereoCalibration

DEFAULT_DELTAS = tuple(np.round(np.arange(-0.5, 0.5001, 0.1), 3))
MIN_STEREO_EDGES = 100


@dataclass
class MapProblem:
    """A whole map as bundle adjustment input: poses ``T_cw`` (the free ones first, the fixed first
    keyframe last), points ``X`` and every observation as ``StereoEdges``."""

    T_cw: np.ndarray
    n_free: int
    X: np.ndarray
    edges: StereoEdges
    keyframe_ids: list
    landmark_ids: list     # the rows of X


@dataclass
class OffsetProfile:
    deltas: np.ndarray     # px, the shifts tried (relative to the map's own measurements)
    costs: np.ndarray      # Huber cost of the converged map BA at each shift
    offset_px: float       # the shift at the fitted minimum
    se_px: float           # its standard error
    n_edges: int
    n_stereo: int


def map_problem(keyframes: dict, landmarks: dict, pixel_sigma: float, scale_factor: float,
                huber_stereo: float, huber_mono: float) -> MapProblem:
    """Every observation of every landmark by a keyframe of ``keyframes`` (a mapper's stores), laid out
    for ``stereo_ba.bundle_adjust_points`` with the first keyframe fixed (gauge)."""
    kf_ids = sorted(keyframes)
    if len(kf_ids) < 3:
        raise ValueError(f"the map has {len(kf_ids)} keyframes: the offset needs at least 3 (the camera must move)")
    order = kf_ids[1:] + kf_ids[:1]
    pose_of = {k: i for i, k in enumerate(order)}
    lm_ids = []   # landmarks with at least one observation by these keyframes
    e_pose, e_pt, meas, octave = [], [], [], []
    for lid in sorted(landmarks):
        seen = [(pose_of[k], kp) for k, kp in landmarks[lid].obs.items() if k in pose_of]
        if not seen:
            continue
        j = len(lm_ids)
        lm_ids.append(lid)
        for i, kp in seen:
            kf = keyframes[order[i]]
            e_pose.append(i)
            e_pt.append(j)
            meas.append((kf.uv[kp, 0], kf.uv[kp, 1], kf.u_right[kp]))
            octave.append(kf.octave[kp])
    meas = np.asarray(meas, float).reshape(-1, 3)
    stereo = meas[:, 2] >= 0
    meas[~stereo, 2] = 0.0
    sigma = pixel_sigma * scale_factor ** np.asarray(octave, float)
    huber = np.where(stereo, huber_stereo, huber_mono)
    edges = StereoEdges(np.asarray(e_pose, np.int64), np.asarray(e_pt, np.int64), meas, stereo, sigma, huber)
    X = np.stack([np.asarray(landmarks[l].position, float) for l in lm_ids]) if lm_ids else np.zeros((0, 3))
    T_cw = np.stack([se3_inv(keyframes[k].T_world_cam) for k in order])
    return MapProblem(T_cw, len(order) - 1, X, edges, order, lm_ids)


def _shifted(edges: StereoEdges, delta: float) -> StereoEdges:
    meas = edges.meas.copy()
    meas[:, 2] = np.where(edges.stereo, meas[:, 2] - delta, 0.0)   # d = u_l - u_r grows by delta
    return StereoEdges(edges.pose, edges.point, meas, edges.stereo, edges.sigma, edges.huber)


def fit_minimum(deltas: np.ndarray, costs: np.ndarray, n_residuals: int) -> tuple[float, float]:
    """(delta at the minimum, standard error) from a parabola through the lowest grid cost and its two
    neighbours; a minimum on the grid's edge is returned as that edge with an infinite error."""
    deltas, costs = np.asarray(deltas, float), np.asarray(costs, float)
    i = int(np.argmin(costs))
    if i == 0 or i == len(costs) - 1:
        return float(deltas[i]), float("inf")
    x, y = deltas[i - 1:i + 2], costs[i - 1:i + 2]
    a, b, c = np.polyfit(x, y, 2)
    if a <= 0:
        return float(deltas[i]), float("inf")
    x0 = -b / (2 * a)
    c_min = float(np.polyval([a, b, c], x0))
    s2 = 2.0 * max(c_min, 1e-12) / max(n_residuals, 1)   # the residuals' own scale (whitened units)
    return float(x0), float(np.sqrt(s2 / (2 * a)))


def map_offset_profile(problem: MapProblem, calib: StereoCalibration, chi2_stereo: float, chi2_mono: float,
                       deltas=DEFAULT_DELTAS, iterations: int = 30, min_depth: float = 1e-6) -> OffsetProfile:
    """The offset profile of a map (module docstring). The map is first converged as measured and its
    inliers (chi2 under the thresholds) kept, so that every shift is judged on the same observations."""
    edges = problem.edges
    n_stereo = int(edges.stereo.sum())
    if n_stereo < MIN_STEREO_EDGES:
        raise ValueError(f"the map has {n_stereo} stereo observations: the offset needs at least {MIN_STEREO_EDGES}")
    T, X, _ = bundle_adjust_points(problem.T_cw, problem.n_free, problem.X, edges, calib, iterations,
                                   relative_tol=1e-7)
    keep = edge_chi2(T, X, edges, calib, min_depth) <= np.where(edges.stereo, chi2_stereo, chi2_mono)
    inliers = edges.take(keep)
    deltas = np.asarray(sorted(deltas), float)
    costs = np.empty(len(deltas))
    for j, d in enumerate(deltas):
        e = _shifted(inliers, d)
        Td, Xd, _ = bundle_adjust_points(T, problem.n_free, X, e, calib, iterations, relative_tol=1e-9)
        r, _, _, front = _project(Td, Xd, e, calib)
        costs[j] = _robust_cost(r, front, e)[0]
    n_res = int(2 * len(inliers.pose) + inliers.stereo.sum())
    offset, se = fit_minimum(deltas, costs, n_res)
    return OffsetProfile(deltas, costs, offset, se, int(len(inliers.pose)), int(inliers.stereo.sum()))
