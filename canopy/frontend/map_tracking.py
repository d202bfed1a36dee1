"""Pose solving of the tracker against the local map (AGRI §3.2.3; ORB-SLAM's
TrackWithMotionModel / TrackLocalMap): projection search, EPnP RANSAC, motion-only refinement.

A mixin of ``canopy.frontend.tracker.Tracker`` (uses its ``params``, ``calib``, ``K`` and
the motion state); the refinement itself is ``canopy.frontend.pose.refine_pose``.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.geometry import pose_from_rvec, project_stereo
from canopy.frontend.map_view import MapView
from canopy.frontend.matching import knn_match, match_in_window
from canopy.frontend.pose import refine_pose
from canopy.frontend.stereo import StereoMatches
from canopy.frontend.stereo_fill import appearance_first_matches


class MapTrackingMixin:
    """3D-2D matching and pose estimation of one frame (see the module docstring)."""

    def _search(self, T_cw, pos, words, feats: Features, kp_words, radius: float, scaled: bool = False):
        """Project points with a pose and match each to the best keypoint within ``radius``."""
        proj, Pc = project_stereo(T_cw, pos, self.calib)
        in_view = ((Pc[:, 2] > 0) & (proj[:, 0] >= 0) & (proj[:, 0] < self.calib.width)
                   & (proj[:, 1] >= 0) & (proj[:, 1] < self.calib.height))
        r_scale = self.scale_factors[feats.octave] if scaled else None
        r_level = feats.octave if scaled and self.params.map_ratio_same_level else None
        q, r, _ = match_in_window(proj[:, :2], words, np.full(len(pos), radius), feats.uv, kp_words,
                                  self.params.map_max_hamming, self.params.map_ratio, q_mask=in_view,
                                  r_scale=r_scale, r_level=r_level)
        return q, r, in_view

    def _initial_matches(self, T_pred_cw, view: MapView, feats: Features, kp_words):
        """Stage 1: 3D-2D correspondences for RANSAC.

        Returns (points (K,3), keypoint indices, landmark ids (-1: not a landmark), descriptor words).
        """
        p = self.params
        enough = 2 * p.min_inliers
        if p.appearance_first_filled and not self._velocity_valid and len(view.ids):
            cand = appearance_first_matches(self, view, feats, enough)  # canopy.frontend.stereo_fill
            if cand is not None:
                return cand
        # ORB-SLAM TrackWithMotionModel: the landmarks matched in the previous frame
        pos, words, lids = self._last_matched
        q, r, _ = self._search(T_pred_cw, pos, words, feats, kp_words, p.search_radius)
        if len(q) < enough:  # widen the window when too few matches
            q, r, _ = self._search(T_pred_cw, pos, words, feats, kp_words, p.search_radius_wide)
        best = (pos[q], r, lids[q], words[q])
        if len(q) < enough:  # the whole local map through the prediction
            q, r, _ = self._search(T_pred_cw, view.pos, view.words, feats, kp_words, p.search_radius_wide)
            if len(q) > len(best[1]):
                best = (view.pos[q], r, view.ids[q], view.words[q])
        if len(best[1]) < enough and len(view.ids):
            # no usable prediction: appearance only (RANSAC sorts out the outliers)
            cand = self._appearance_matches(view, feats)
            if len(cand[1]) > len(best[1]):
                best = cand
        if len(best[1]) < enough and self._last_points_w is not None and len(self._last_points_w):
            # last resort: the previous frame's stereo points (frame-to-frame odometry)
            q3, r3, _ = self._search(T_pred_cw, self._last_points_w, self._last_words, feats, kp_words,
                                     p.search_radius_wide)
            if len(q3) > len(best[1]):
                best = (self._last_points_w[q3], r3, np.full(len(q3), -1, np.int64), self._last_words[q3])
        return best

    def _appearance_matches(self, view: MapView, feats: Features):
        """Local-map points matched to keypoints by descriptor alone (ORB-SLAM's
        TrackReferenceKeyFrame role: no pose needed), as (points, keypoints, ids, words)."""
        p = self.params
        if len(view.ids) == 0:
            return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), view.words[:0]
        r2, q2, _ = knn_match(feats.descriptors, view.desc, p.map_max_hamming, p.map_ratio)
        return view.pos[q2], r2, view.ids[q2], view.words[q2]

    def _explained_by_prediction(self, T_pred_cw: np.ndarray, X: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Stage-1 matches the constant-velocity prediction can explain: projected within the wide
        search radius of their keypoint (matches hundreds of pixels off cannot be right if the motion is)."""
        if len(X) == 0:
            return np.zeros(0, bool)
        proj, Pc = project_stereo(T_pred_cw, X, self.calib)
        err = np.linalg.norm(proj[:, :2] - uv, axis=1)
        return (Pc[:, 2] > 0) & (err <= self.params.search_radius_wide)

    def _start_from_prediction(self, T_pred_cw: np.ndarray, X: np.ndarray, uv: np.ndarray, inliers: np.ndarray):
        """RANSAC found no pose (hazy, noisy frames: a quarter of the appearance matches right, too few
        for 100 EPnP samples): (prediction, the matches it explains, True) to refine from, as ORB-SLAM's
        TrackWithMotionModel does (no RANSAC, a robust refinement from the predicted pose); (None,
        ``inliers``, False) when it explains fewer than min_inliers."""
        near = self._explained_by_prediction(T_pred_cw, X, uv)
        if near.sum() >= self.params.min_inliers:
            return T_pred_cw, near, True
        return None, inliers, False

    def _ransac(self, frame_index: int, X: np.ndarray, uv: np.ndarray):
        """EPnP inside RANSAC (AGRI §3.2.3), seeded per frame for determinism."""
        p = self.params
        if len(X) < p.min_inliers:
            return None, np.zeros(len(X), bool)
        cv2.setRNGSeed(p.seed + frame_index)
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            np.ascontiguousarray(X, np.float64).reshape(-1, 1, 3),
            np.ascontiguousarray(uv, np.float64).reshape(-1, 1, 2), self.K, None,
            iterationsCount=p.pnp_iterations, reprojectionError=p.pnp_reprojection_error,
            confidence=p.pnp_confidence, flags=cv2.SOLVEPNP_EPNP)
        mask = np.zeros(len(X), bool)
        if not found or inl is None or len(inl) < p.min_inliers:
            return None, mask
        mask[inl.reshape(-1)] = True
        return pose_from_rvec(rvec, tvec), mask

    def _refine(self, T_cw, X, r, feats: Features, stereo: StereoMatches, inliers=None, line_obs=None, extra=None):
        """Motion-only refinement; with ``line_obs`` = (A_w, B_w, line coefficients) the Eq. 10
        line terms join the point terms (Eq. 11 with the map fixed); ``extra``: more terms for the
        point-only solve (``pose.ExtraTerms``, e.g. the motion prior)."""
        p = self.params
        meas = np.concatenate([feats.uv[r].astype(np.float64), stereo.u_right[r, None].astype(np.float64)], axis=1)
        if line_obs is None:
            return refine_pose(T_cw, X, meas, stereo.valid[r], self._sigma(feats.octave[r]), self.calib,
                               p.pose_opt_rounds, p.pose_opt_iterations, p.chi2_mono, p.chi2_stereo, inliers=inliers,
                               extra=extra)
        A_w, B_w, coeffs = line_obs
        return self._lt.refine_pose_points_lines(T_cw, X, meas, stereo.valid[r], self._sigma(feats.octave[r]), self.calib,
                                                 p.pose_opt_rounds, p.pose_opt_iterations, p.chi2_mono, p.chi2_stereo,
                                                 A_w, B_w, coeffs, p.line_sigma, p.chi2_line, inliers=inliers)

    def _n_support(self, est) -> int:
        """Inlier count deciding success: points, plus lines (x line_weight_in_count) when on."""
        n = int(est.inliers.sum())
        if self._lines_on and hasattr(est, "line_inliers"):
            n += self.params.line_weight_in_count * int(est.line_inliers.sum())
        return n

