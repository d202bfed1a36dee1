"""Stereo line matching on rectified pairs (AGRI §3.2.2 for segments; after PL-SLAM).

For each left segment that is not near-horizontal: right segments whose row range overlaps
it (shared rows / shorter row range >= ``min_vertical_overlap``), whose oriented direction
agrees within ``max_angle_diff_deg``, and whose infinite line, intersected with the rows of
the two left endpoints, gives disparities within [min_disparity, max_disparity] at both
endpoints; among those the best LBD Hamming distance <= ``stereo_max_hamming`` with
best < ``stereo_ratio`` * second best; each right segment kept for its closest left segment.
The endpoint disparities come from that intersection (a rectified pair shares rows, so the
left endpoint's correspondent lies on the right line at the same row), and the endpoints
are back-projected into the left camera frame.

Candidate pairs come from row bands over right segments sorted by their top row
(``canopy.frontend.matching.band_pairs``), never the full N x M product.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy.frontend.matching import as_words, band_pairs, best_two, hamming_pairs, unique_by_reference
from canopy.lines.params import LineParams
from shared.types import StereoCalibration

_MIN_ROW_SPAN = 1e-6  # px; a right line flatter than this has no row intersection


@dataclass
class StereoLines:
    """Stereo matches of left segments (K rows, indices into the left / right segment arrays)."""

    left_idx: np.ndarray     # (K,) int64
    right_idx: np.ndarray    # (K,) int64
    distance: np.ndarray     # (K,) Hamming distance of the LBD descriptors
    disparity: np.ndarray    # (K,2) px at the left start / end point
    points_cam: np.ndarray   # (K,2,3) start / end point in the left camera frame (m)
    overlap: np.ndarray      # (K,) shared rows / shorter row range
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.left_idx)


def _empty(stats: dict) -> StereoLines:
    return StereoLines(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                       np.zeros((0, 2)), np.zeros((0, 2, 3)), np.zeros(0), stats)


def backproject(u: np.ndarray, v: np.ndarray, disparity: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    """(N,3) left-camera points from pixel (u, v) and disparity (z = bf / d)."""
    z = calib.bf / disparity
    return np.stack([(u - calib.cx) * z / calib.fx, (v - calib.cy) * z / calib.fy, z], axis=-1)


def stereo_candidates(segs_l: np.ndarray, segs_r: np.ndarray, calib: StereoCalibration, params: LineParams):
    """Geometric stereo candidates (no descriptors): left indices, right indices, vertical
    overlap and endpoint disparities (K,2) of every pair passing the gates of the module doc."""
    sl = np.asarray(segs_l, np.float64).reshape(-1, 4)
    sr = np.asarray(segs_r, np.float64).reshape(-1, 4)
    n_l, n_r = len(sl), len(sr)
    stats = {"left": n_l, "right": n_r, "horizontal": 0, "candidates": 0, "matched": 0}
    none = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2)), stats)
    if n_l == 0 or n_r == 0:
        return none

    dl, dr = sl[:, 2:] - sl[:, :2], sr[:, 2:] - sr[:, :2]
    len_l = np.hypot(dl[:, 0], dl[:, 1])
    steep = np.abs(dl[:, 1]) >= len_l * np.sin(np.deg2rad(params.min_angle_from_horizontal_deg))
    stats["horizontal"] = int((~steep).sum())
    q = np.flatnonzero(steep)
    if len(q) == 0:
        return none

    lo_l, hi_l = np.minimum(sl[:, 1], sl[:, 3]), np.maximum(sl[:, 1], sl[:, 3])
    lo_r, hi_r = np.minimum(sr[:, 1], sr[:, 3]), np.maximum(sr[:, 1], sr[:, 3])
    order = np.argsort(lo_r, kind="stable")
    # every right segment overlapping [lo_l, hi_l] has its top row in [lo_l - max height, hi_l]
    max_h = float((hi_r - lo_r).max())
    qi, rpos = band_pairs(lo_l[q] - max_h, hi_l[q], lo_r[order])
    li, rj = q[qi], order[rpos]

    shared = np.minimum(hi_l[li], hi_r[rj]) - np.maximum(lo_l[li], lo_r[rj])
    shorter = np.maximum(np.minimum(hi_l[li] - lo_l[li], hi_r[rj] - lo_r[rj]), _MIN_ROW_SPAN)
    overlap = shared / shorter
    ang_l, ang_r = np.arctan2(dl[:, 1], dl[:, 0]), np.arctan2(dr[:, 1], dr[:, 0])
    dang = np.abs((ang_l[li] - ang_r[rj] + np.pi) % (2 * np.pi) - np.pi)
    ok = (overlap >= params.min_vertical_overlap) & (dang <= np.deg2rad(params.max_angle_diff_deg))
    ok &= np.abs(dr[rj, 1]) > _MIN_ROW_SPAN
    li, rj, overlap = li[ok], rj[ok], overlap[ok]

    # right infinite line at the rows of the left endpoints: u_r(v) = x0 + (v - y0) * dx / dy
    slope = dr[rj, 0] / dr[rj, 1]
    ur1 = sr[rj, 0] + (sl[li, 1] - sr[rj, 1]) * slope
    ur2 = sr[rj, 0] + (sl[li, 3] - sr[rj, 1]) * slope
    disp = np.column_stack([sl[li, 0] - ur1, sl[li, 2] - ur2])
    max_disp = params.max_disparity_fraction * calib.width
    ok = ((disp >= params.min_disparity) & (disp <= max_disp)).all(axis=1)
    li, rj, overlap, disp = li[ok], rj[ok], overlap[ok], disp[ok]
    stats["candidates"] = int(len(li))
    return li, rj, overlap, disp, stats


def right_segments_in_reach(segs_l: np.ndarray, segs_r: np.ndarray, calib: StereoCalibration,
                            params: LineParams) -> np.ndarray:
    """Mask of the right segments that are a stereo candidate of some left segment: only these
    can be matched, so only these need an LBD descriptor."""
    rj = stereo_candidates(segs_l, segs_r, calib, params)[1]
    mask = np.zeros(len(np.asarray(segs_r).reshape(-1, 4)), bool)
    mask[rj] = True
    return mask


def match_stereo_lines(segs_l: np.ndarray, desc_l: np.ndarray, segs_r: np.ndarray, desc_r: np.ndarray,
                       calib: StereoCalibration, params: LineParams) -> StereoLines:
    sl = np.asarray(segs_l, np.float64).reshape(-1, 4)
    n_l = len(sl)
    li, rj, overlap, disp, stats = stereo_candidates(segs_l, segs_r, calib, params)
    if len(li) == 0:
        return _empty(stats)

    dist = hamming_pairs(as_words(desc_l), as_words(desc_r), li, rj)
    # best_two works on positions; keep a per-pair index to recover overlap and disparity
    pair = np.arange(len(li))
    best_pair, best_d, second_d = best_two(li, pair, dist, n_l)
    good = (best_pair >= 0) & (best_d <= params.stereo_max_hamming) & (best_d < params.stereo_ratio * second_d)
    sel_l = np.flatnonzero(good)
    sel_p = best_pair[sel_l]
    keep = unique_by_reference(sel_l, rj[sel_p], best_d[sel_l])
    sel_l, sel_p = sel_l[keep], sel_p[keep]

    d = disp[sel_p]
    pts = np.stack([backproject(sl[sel_l, 0], sl[sel_l, 1], d[:, 0], calib),
                    backproject(sl[sel_l, 2], sl[sel_l, 3], d[:, 1], calib)], axis=1)
    stats["matched"] = int(len(sel_l))
    return StereoLines(sel_l.astype(np.int64), rj[sel_p].astype(np.int64), best_d[sel_l].astype(np.int64),
                       d, pts, overlap[sel_p], stats)
