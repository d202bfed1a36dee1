"""Geometric verification of a loop candidate (AGRI §3.4.1; ORB-SLAM ComputeSim3 for stereo).

A candidate that looks alike is a loop only if the geometry agrees. With stereo the scale
is known, so the loop constraint is an SE(3) pose (ORB-SLAM2 stereo fixes the Sim3 scale
to 1):

1. descriptor matches between the query's keypoints and the candidate's keypoints that
   have stereo depth, within a vocabulary node when a vocabulary gives one (DBoW2's
   direct index, what ORB-SLAM's SearchByBoW does), otherwise brute force with Lowe's
   ratio test;
2. RANSAC for T_query_cand: three matched stereo points per hypothesis in closed form,
   scored by reprojecting the candidate points into the query image
   (``canopy.loop.rigid_ransac``; or EPnP on candidate points against query pixels);
3. guided search: every candidate stereo point projected with that pose and matched in a
   small window (ORB-SLAM SearchByProjection), then motion-only refinement on the
   query's stereo measurements (AGRI Eq. 9 with Huber, re-classification of outliers);
4. accepted when at least ``min_inliers`` measurements survive.

The constraint does not depend on the drifted world poses of the two keyframes: it is
measured between the two cameras only.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy.frontend.geometry import pose_from_rvec, se3_inv
from canopy.frontend.matching import as_words, best_two, hamming_pairs, knn_match, match_in_window, unique_by_reference
from canopy.frontend.pose import refine_pose
from canopy.loop.keyframe import PlaceKeyframe
from canopy.loop.params import LoopParams
from canopy.loop.rigid_ransac import rigid_ransac
from shared.types import StereoCalibration


@dataclass
class LoopConstraint:
    query: int                 # keyframe (or frame) index of the query
    candidate: int             # keyframe index of the matched place
    T_cand_query: np.ndarray   # (4,4) query camera in the candidate camera frame
    n_matches: int             # descriptor matches fed to RANSAC
    n_inliers: int             # measurements kept by the refinement
    information: np.ndarray    # (6,6) information of the query pose given the candidate's points
    query_keypoints: np.ndarray      # (M,) inlier keypoints of the query
    candidate_keypoints: np.ndarray  # (M,) their matched candidate keypoints


@dataclass
class Verification:
    constraint: LoopConstraint | None
    reason: str                # "ok" or why the candidate was rejected
    n_matches: int = 0
    n_inliers: int = 0

    @property
    def kind(self) -> str:
        """The stage that rejected the candidate (for counting): features, matches, ransac, refinement."""
        if self.constraint is not None:
            return "ok"
        for key in ("features", "matches", "RANSAC", "refinement"):
            if key in self.reason:
                return key.lower()
        return "other"


def match_by_nodes(q_desc: np.ndarray, q_nodes: np.ndarray, r_desc: np.ndarray, r_nodes: np.ndarray,
                   max_hamming: int, ratio: float):
    """Matches only between features under the same vocabulary node (DBoW2 direct index):
    all same-node pairs at once, best and second best per query, each reference used once."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(q_desc) == 0 or len(r_desc) == 0:
        return empty
    order = np.argsort(r_nodes, kind="stable")
    sorted_nodes = r_nodes[order]
    lo = np.searchsorted(sorted_nodes, q_nodes, side="left")
    hi = np.searchsorted(sorted_nodes, q_nodes, side="right")
    counts = hi - lo
    total = int(counts.sum())
    if total == 0:
        return empty
    qi = np.repeat(np.arange(len(q_desc)), counts)
    rj = order[np.repeat(lo - np.cumsum(counts) + counts, counts) + np.arange(total)]
    dist = hamming_pairs(as_words(q_desc), as_words(r_desc), qi, rj)
    best_ref, best_d, second_d = best_two(qi, rj, dist, len(q_desc))
    good = (best_ref >= 0) & (best_d <= max_hamming) & (best_d < ratio * second_d)
    q = np.flatnonzero(good)
    r, d = best_ref[q], best_d[q]
    keep = unique_by_reference(q, r, d)
    return q[keep], r[keep], d[keep].astype(np.int64)


def _pnp_ransac(X: np.ndarray, uv: np.ndarray, K: np.ndarray, params: LoopParams, seed: int):
    cv2.setRNGSeed(int(seed))
    found, rvec, tvec, inl = cv2.solvePnPRansac(
        np.ascontiguousarray(X, np.float64).reshape(-1, 1, 3), np.ascontiguousarray(uv, np.float64).reshape(-1, 1, 2),
        K, None, iterationsCount=params.pnp_iterations, reprojectionError=params.pnp_reprojection_error,
        confidence=params.pnp_confidence, flags=cv2.SOLVEPNP_EPNP)
    if not found or inl is None:
        return None, np.zeros(len(X), bool)
    mask = np.zeros(len(X), bool)
    mask[inl.reshape(-1)] = True
    return pose_from_rvec(rvec, tvec), mask


def verify_candidate(query: PlaceKeyframe, cand: PlaceKeyframe, calib: StereoCalibration, params: LoopParams,
                     vocabulary=None) -> Verification:
    """Stereo PnP verification of ``cand`` as the place ``query`` sees (see module doc)."""
    c_sel = np.flatnonzero(cand.has_depth)
    if len(c_sel) < params.min_matches or len(query) < params.min_matches:
        return Verification(None, "too few features")
    X_c = cand.points_cam(calib)
    # 1. descriptor matches (direct index when both sides carry vocabulary words)
    use_nodes = (vocabulary is not None and hasattr(vocabulary, "node_ids")
                 and len(query.word_ids) == len(query) and len(cand.word_ids) == len(cand))
    if use_nodes:
        lv = params.direct_index_levels_up
        qn = np.asarray(vocabulary.node_ids(query.word_ids, lv), np.int64)
        cn = np.asarray(vocabulary.node_ids(cand.word_ids[c_sel], lv), np.int64)
        qi, cj, _ = match_by_nodes(query.descriptors, qn, cand.descriptors[c_sel], cn, params.max_hamming,
                                   params.match_ratio)
    else:
        qi, cj, _ = knn_match(query.descriptors, cand.descriptors[c_sel], params.max_hamming, params.match_ratio)
    cj = c_sel[cj]
    n_matches = len(qi)
    if n_matches < params.min_matches:
        return Verification(None, f"{n_matches} descriptor matches < {params.min_matches}", n_matches)
    # 2. RANSAC: candidate camera points -> query pixels
    seed = query.index * 7919 + cand.index
    X_q = query.points_cam(calib)[qi]
    # three-point rigid hypotheses need stereo on the query side too (a monocular query goes to EPnP)
    if params.verify_ransac == "rigid" and np.isfinite(X_q[:, 2]).sum() >= 3:
        T_qc, mask = rigid_ransac(X_c[cj], X_q, query.uv[qi], calib.K, params.pnp_reprojection_error,
                                  params.pnp_iterations, params.pnp_confidence, seed)
    else:
        T_qc, mask = _pnp_ransac(X_c[cj], query.uv[qi], calib.K, params, seed=seed)
    if T_qc is None or mask.sum() < params.min_pnp_inliers:
        return Verification(None, f"PnP RANSAC: {int(mask.sum())} inliers < {params.min_pnp_inliers}", n_matches,
                            int(mask.sum()))
    scale = params.scale_factor ** np.asarray(query.octave, float)
    sigma_q = params.pixel_sigma * scale

    def refine(T, q_idx, c_idx):
        meas = np.concatenate([query.uv[q_idx], np.asarray(query.u_right, float)[q_idx, None]], axis=1)
        return refine_pose(T, X_c[c_idx], meas, query.has_depth[q_idx], sigma_q[q_idx], calib,
                           params.refine_rounds, params.refine_iterations, params.chi2_mono, params.chi2_stereo)

    est = refine(T_qc, qi[mask], cj[mask])
    T_qc = est.T_cam_world
    # 3. guided search with the refined pose over all candidate stereo points, then refine again
    Pq = X_c[c_sel] @ T_qc[:3, :3].T + T_qc[:3, 3]
    z = np.where(Pq[:, 2] > 1e-6, Pq[:, 2], np.nan)
    proj = np.stack([calib.fx * Pq[:, 0] / z + calib.cx, calib.fy * Pq[:, 1] / z + calib.cy], axis=1)
    in_view = (np.isfinite(proj).all(axis=1) & (proj[:, 0] >= 0) & (proj[:, 0] < calib.width)
               & (proj[:, 1] >= 0) & (proj[:, 1] < calib.height))
    proj = np.where(in_view[:, None], proj, -1e6)
    g_c, g_q, _ = match_in_window(proj, as_words(cand.descriptors[c_sel]), np.full(len(c_sel), params.guided_search_radius),
                                  np.asarray(query.uv, float), as_words(query.descriptors), params.max_hamming,
                                  params.match_ratio, q_mask=in_view)
    if len(g_q) >= est.inliers.sum():
        est = refine(T_qc, g_q, c_sel[g_c])
        qi_f, cj_f = g_q, c_sel[g_c]
    else:
        qi_f, cj_f = qi[mask], cj[mask]
    n_inl = int(est.inliers.sum())
    if n_inl < params.min_inliers:
        return Verification(None, f"refinement: {n_inl} inliers < {params.min_inliers}", n_matches, n_inl)
    constraint = LoopConstraint(query=query.index, candidate=cand.index, T_cand_query=se3_inv(est.T_cam_world),
                                n_matches=n_matches, n_inliers=n_inl, information=est.information,
                                query_keypoints=qi_f[est.inliers], candidate_keypoints=cj_f[est.inliers])
    return Verification(constraint, "ok", n_matches, n_inl)
