"""Line features in tracking (AGRI §3.2.1-3.2.3 for segments, Eq. 10-11; issue 4).

* ``LineFrame``: a frame's left segments, their LBD descriptors and infinite lines.
* ``LineMapView``: tracking's copy of the local map's line landmarks (endpoints A, B in world).
* ``match_map_lines``: temporal matching. Map lines are projected with a pose; a segment is a
  candidate for a map line when its directed angle to the projected line is within a gate,
  both its endpoints lie within ``radius`` px of the projected infinite line and it overlaps
  the projected segment along the line; among candidates the best LBD Hamming distance wins
  (threshold + ratio test), each segment kept for its closest map line.
* ``LineTerms`` / ``refine_pose_points_lines``: ``canopy.frontend.pose.refine_pose`` with Eq. 10 line
  residuals (distances of the projected 3D endpoints to the observed infinite line) added
  to the Gauss-Newton normal equations, weighted by Sigma^-1 = I / line_sigma^2 (Eq. 11),
  with the same Huber kernel and chi-square outlier rounds as the points.

Everything is vectorised over lines (the dense map x frame gate is at most a few hundred by
``line_max_lines``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy.frontend.geometry import transform
from canopy.frontend.matching import as_words, best_two, hamming_pairs, unique_by_reference
from canopy.frontend.pose import PoseEstimate, refine_pose
from canopy.lines import line_coefficients
from shared.types import StereoCalibration

_MIN_DEPTH = 1e-3          # m; endpoints closer to (or behind) the camera are not projected
_CONVERGED_STEP = 1e-8     # as canopy.frontend.pose
_OVERLAP_MARGIN = 0.1      # fraction of the projected length an observed segment may lie beyond it


@dataclass
class LineFrame:
    """Left segments of one frame with LBD descriptors and normalised infinite lines."""

    segs: np.ndarray                 # (N,4) float64 px
    desc: np.ndarray                 # (N,32) uint8
    coeffs: np.ndarray               # (N,3) line_coefficients (l . x~ = signed px distance)
    stats: dict = field(default_factory=dict)

    @classmethod
    def build(cls, segs: np.ndarray, desc: np.ndarray, stats: dict | None = None) -> "LineFrame":
        segs = np.asarray(segs, np.float64).reshape(-1, 4)
        return cls(segs, np.ascontiguousarray(desc, np.uint8).reshape(-1, 32), line_coefficients(segs),
                   dict(stats or {}))

    def __len__(self) -> int:
        return len(self.segs)


class LineMapView:
    """Line landmarks: ids, endpoints A, B (world) and LBD descriptors."""

    def __init__(self):
        self.set(np.zeros(0, np.int64), np.zeros((0, 2, 3)), np.zeros((0, 32), np.uint8))

    def set(self, ids, endpoints, desc) -> None:
        self.ids = np.asarray(ids, np.int64).reshape(-1)
        self.endpoints = np.asarray(endpoints, np.float64).reshape(-1, 2, 3)
        self.desc = np.ascontiguousarray(desc, np.uint8).reshape(-1, 32)
        self.words = as_words(self.desc)

    @property
    def A(self) -> np.ndarray:
        return self.endpoints[:, 0]

    @property
    def B(self) -> np.ndarray:
        return self.endpoints[:, 1]

    def __len__(self) -> int:
        return len(self.ids)


def project_segments(T_cw: np.ndarray, A_w: np.ndarray, B_w: np.ndarray, calib: StereoCalibration):
    """(M,4) projected segments (left camera, Eq. 8) and a mask of those in front of it."""
    PA, PB = transform(T_cw, A_w), transform(T_cw, B_w)
    front = (PA[:, 2] > _MIN_DEPTH) & (PB[:, 2] > _MIN_DEPTH)
    za = np.where(front, PA[:, 2], 1.0)
    zb = np.where(front, PB[:, 2], 1.0)
    seg = np.column_stack([calib.fx * PA[:, 0] / za + calib.cx, calib.fy * PA[:, 1] / za + calib.cy,
                           calib.fx * PB[:, 0] / zb + calib.cx, calib.fy * PB[:, 1] / zb + calib.cy])
    return seg, front


def match_map_lines(T_cw: np.ndarray, view: LineMapView, frame: LineFrame, calib: StereoCalibration,
                    radius: float, max_angle_deg: float, max_hamming: int, ratio: float):
    """Temporal line matches: (map indices, frame segment indices, Hamming distances)."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(view) == 0 or len(frame) == 0:
        return empty
    proj, front = project_segments(T_cw, view.A, view.B, calib)
    x, y = proj[:, [0, 2]], proj[:, [1, 3]]
    in_image = front & ~(((x < 0) | (x >= calib.width)).all(axis=1) | ((y < 0) | (y >= calib.height)).all(axis=1))
    q = np.flatnonzero(in_image)
    if len(q) == 0:
        return empty
    p = proj[q]
    d_map = p[:, 2:] - p[:, :2]
    len_map = np.hypot(d_map[:, 0], d_map[:, 1])
    q, p, d_map, len_map = q[len_map > 1.0], p[len_map > 1.0], d_map[len_map > 1.0], len_map[len_map > 1.0]
    if len(q) == 0:
        return empty
    t_map = d_map / len_map[:, None]                       # (M',2) unit direction
    n_map = np.column_stack([-t_map[:, 1], t_map[:, 0]])   # unit normal
    s = frame.segs
    d_obs = s[:, 2:] - s[:, :2]
    t_obs = d_obs / np.hypot(d_obs[:, 0], d_obs[:, 1])[:, None]
    # dense (M', N) gates: directed angle, endpoint distances to the projected infinite line,
    # overlap along the projected segment
    cos_ang = t_map @ t_obs.T
    rel_a = s[None, :, :2] - p[:, None, :2]                 # (M',N,2)
    rel_b = s[None, :, 2:] - p[:, None, :2]
    dist = np.maximum(np.abs(np.einsum("mnk,mk->mn", rel_a, n_map)), np.abs(np.einsum("mnk,mk->mn", rel_b, n_map)))
    ta = np.einsum("mnk,mk->mn", rel_a, t_map) / len_map[:, None]
    tb = np.einsum("mnk,mk->mn", rel_b, t_map) / len_map[:, None]
    overlap = (np.minimum(np.maximum(ta, tb), 1.0 + _OVERLAP_MARGIN)
               - np.maximum(np.minimum(ta, tb), -_OVERLAP_MARGIN)) > 0
    ok = (cos_ang >= np.cos(np.deg2rad(max_angle_deg))) & (dist <= radius) & overlap
    mi, rj = np.nonzero(ok)
    if len(mi) == 0:
        return empty
    qi = q[mi]
    hd = hamming_pairs(view.words, as_words(frame.desc), qi, rj)
    best_ref, best_d, second_d = best_two(qi, rj, hd, len(view))
    good = (best_ref >= 0) & (best_d <= max_hamming) & (best_d < ratio * second_d)
    qsel = np.flatnonzero(good)
    rsel, dsel = best_ref[qsel], best_d[qsel]
    keep = unique_by_reference(qsel, rsel, dsel)
    return qsel[keep], rsel[keep], dsel[keep]


def _line_terms(T_cw, A_w, B_w, coeffs, calib: StereoCalibration):
    """Eq. 10 residuals (N,2), their pose Jacobians (N,2,6) and a mask of lines with both
    endpoints in front, from one transform of the endpoints.

    Per endpoint with camera point P and distance gradient g = d e / d P: perturbing T_cw on
    the left by xi = (omega, v) moves P by omega x P + v, so d e / d xi = (P x g, g).
    """
    R, t = T_cw[:3, :3], T_cw[:3, 3]
    n = len(A_w)
    P = np.concatenate([A_w, B_w]) @ R.T + t                      # (2N,3): A rows, then B rows
    x, y, z = P[:, 0], P[:, 1], P[:, 2]
    ok = z > _MIN_DEPTH
    front = ok[:n] & ok[n:]
    iz = 1.0 / np.where(ok, z, 1.0)
    l = np.concatenate([coeffs, coeffs])
    a = l[:, 0] * calib.fx * iz
    b = l[:, 1] * calib.fy * iz
    ab = a * x + b * y
    e = ab + l[:, 0] * calib.cx + l[:, 1] * calib.cy + l[:, 2]
    c = -ab * iz                                                   # g = (a, b, c)
    J = np.empty((2 * n, 6))
    J[:, 0] = y * c - z * b                                        # P x g
    J[:, 1] = z * a - x * c
    J[:, 2] = x * b - y * a
    J[:, 3], J[:, 4], J[:, 5] = a, b, c
    return e.reshape(2, n).T, J.reshape(2, n, 6).transpose(1, 0, 2), front


def line_chi2(T_cw, A_w, B_w, coeffs, sigma: float, calib: StereoCalibration) -> np.ndarray:
    """Eq. 11 line term per line: (d_a^2 + d_b^2) / sigma^2 (inf when an endpoint is behind)."""
    e, _, front = _line_terms(T_cw, A_w, B_w, coeffs, calib)
    chi2 = (e**2).sum(axis=1) / sigma**2
    chi2[~front | ~np.isfinite(chi2)] = np.inf
    return chi2


def line_information(T_cw, A_w, B_w, coeffs, sigma: float, calib: StereoCalibration) -> np.ndarray:
    """(6,6) pose information J^T Sigma^-1 J of Eq. 10 residuals (Sigma = sigma^2 I)."""
    if len(A_w) == 0:
        return np.zeros((6, 6))
    J = _line_terms(T_cw, A_w, B_w, coeffs, calib)[1].reshape(-1, 6)
    return J.T @ J / sigma**2


@dataclass
class PointLineEstimate(PoseEstimate):
    line_inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    line_chi2: np.ndarray = field(default_factory=lambda: np.zeros(0))


class LineTerms:
    """The Eq. 10 line residuals as extra terms of ``refine_pose`` (Eq. 11 weights
    Sigma^-1 = I / line_sigma^2, Huber width sqrt(chi2_line), chi-square outlier rounds)."""

    def __init__(self, A_w, B_w, coeffs, line_sigma: float, chi2_line: float, calib: StereoCalibration):
        self.A_w = np.asarray(A_w, float).reshape(-1, 3)
        self.B_w = np.asarray(B_w, float).reshape(-1, 3)
        self.coeffs = np.asarray(coeffs, float).reshape(-1, 3)
        self.sigma, self.chi2_line, self.calib = float(line_sigma), float(chi2_line), calib
        self.k = np.sqrt(chi2_line)
        self.inliers = np.ones(len(self.A_w), bool)
        self.chi2 = np.zeros(len(self.A_w))

    def start_round(self) -> int:
        lidx = np.flatnonzero(self.inliers)
        self._A, self._B, self._c = self.A_w[lidx], self.B_w[lidx], self.coeffs[lidx]
        return 2 * len(lidx)

    def normal_equations(self, T_cw: np.ndarray, robust: bool) -> tuple[np.ndarray, np.ndarray]:
        if len(self._A) == 0:
            return np.zeros((6, 6)), np.zeros(6)
        # Eq. 10: e = (l . pi~(T A), l . pi~(T B)); the residual to drive to zero is -e
        e, Jl, fin = _line_terms(T_cw, self._A, self._B, self._c, self.calib)
        lchi2 = (e**2).sum(axis=1) / self.sigma**2
        fin &= np.isfinite(lchi2)
        wl = np.where(fin, 1.0 / self.sigma**2, 0.0)
        if robust:
            el = np.sqrt(np.where(fin, lchi2, 0.0))
            wl = wl * np.where(el <= self.k, 1.0, self.k / np.maximum(el, 1e-12))
        Jf = np.where(fin[:, None, None], Jl, 0.0).reshape(-1, 6)
        Jw = Jf * np.repeat(wl, 2)[:, None]
        return Jw.T @ Jf, -(Jw.T @ np.where(fin[:, None], e, 0.0).reshape(-1))

    def classify(self, T_cw: np.ndarray) -> None:
        self.chi2 = line_chi2(T_cw, self.A_w, self.B_w, self.coeffs, self.sigma, self.calib)
        self.inliers = self.chi2 <= self.chi2_line

    def information(self, T_cw: np.ndarray) -> np.ndarray:
        m = self.inliers
        return line_information(T_cw, self.A_w[m], self.B_w[m], self.coeffs[m], self.sigma, self.calib)


def refine_pose_points_lines(T_cw: np.ndarray, X_w: np.ndarray, meas: np.ndarray, has_right: np.ndarray,
                             sigma: np.ndarray, calib: StereoCalibration, rounds: int, iterations: int,
                             chi2_mono: float, chi2_stereo: float, A_w: np.ndarray, B_w: np.ndarray,
                             coeffs: np.ndarray, line_sigma: float, chi2_line: float,
                             inliers: np.ndarray | None = None) -> PointLineEstimate:
    """Motion-only Gauss-Newton on AGRI Eq. 11 with the map fixed: the point terms of
    ``refine_pose`` (Eq. 9) plus the line terms of Eq. 10."""
    lines = LineTerms(A_w, B_w, coeffs, line_sigma, chi2_line, calib)
    est = refine_pose(T_cw, X_w, meas, has_right, sigma, calib, rounds, iterations, chi2_mono, chi2_stereo,
                      inliers=inliers, extra=lines)
    return PointLineEstimate(est.T_cam_world, est.inliers, est.information, est.chi2, lines.inliers, lines.chi2)
