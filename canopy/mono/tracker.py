"""Monocular tracking (ORB-SLAM Tracking, monocular branch) on the left image only.

States: not initialised -> ok <-> lost (-> not initialised again after
``lost_frames_to_reset`` lost frames: a new map segment, with a new scale).

* Not initialised: the first frame with enough keypoints becomes the reference; every next
  frame is matched to it in a window around where its keypoints were last matched (ORB-SLAM
  SearchForInitialization) and ``initialise_two_view`` tries H/F; the reference is replaced
  when too few matches remain. Success emits two keyframes (reference and current) carrying
  the scale-free initial map (median depth 1): the reference keyframe's ``depth`` field holds
  the triangulated depths and ``new_landmark_ids`` the ids reserved for them.
* Ok: constant-velocity prediction; the landmarks matched in the last frame, then the local
  map, are projected and searched in a window; EPnP RANSAC on those 3D-2D matches; the whole
  local map is projected again through that pose and the pose is refined on monocular
  reprojection errors (``canopy.frontend.pose.refine_pose`` with no right-image residuals).
* Keyframes (ORB-SLAM NeedNewKeyFrame, monocular): after ``max_frames_between_keyframes``
  frames, or when the tracked landmarks fall below ``keyframe_tracked_ratio`` of those tracked
  right after the last keyframe; new points come from local mapping's triangulation.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from canopy.frontend.features import Features, OrbExtractor
from canopy.frontend.geometry import pose_from_rvec, project_stereo, se3_inv, transform
from canopy.frontend.map_view import seen_counts
from canopy.frontend.matching import as_words, knn_match, match_in_window, unique_by_reference
from canopy.frontend.messages import KeyframeData, LocalMapUpdate, TrackingResult
from canopy.frontend.params import TrackingParams
from canopy.frontend.pose import refine_pose
from canopy.mono.params import MonoParams
from canopy.mono.two_view import initialise_two_view
from shared.types import StereoCalibration, StereoFrame

# "not_initialised": no map yet, so no pose (kept out of trajectory.tum like a lost frame)
STATUS_INIT, STATUS_OK, STATUS_LOST = "not_initialised", "ok", "lost"
_EMPTY_DESC = np.zeros((0, 32), np.uint8)


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


@dataclass
class MonoTrackingResult(TrackingResult):
    """A ``TrackingResult`` with every keyframe the frame produced, in order: two at the
    initialisation (reference and current), else none or one (``keyframe``)."""

    keyframes: list[KeyframeData] = field(default_factory=list)


def window_knn(q_uv, q_desc, r_uv, r_desc, radius: float, max_hamming: int, ratio: float):
    """Best reference keypoint within ``radius`` px of each query position (Hamming distance
    <= ``max_hamming``, < ``ratio`` x the second best in the window), each reference used once:
    ORB-SLAM SearchForInitialization. The window is a mask for OpenCV's brute-force matcher."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    if len(q_uv) == 0 or len(r_uv) == 0:
        return empty
    qf, rf = np.asarray(q_uv, np.float32), np.asarray(r_uv, np.float32)
    d2 = (qf[:, 0:1] - rf[:, 0]) ** 2
    d2 += (qf[:, 1:2] - rf[:, 1]) ** 2
    mask = (d2 <= radius * radius).astype(np.uint8)
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(np.ascontiguousarray(q_desc), np.ascontiguousarray(r_desc), k=2,
                                                   mask=mask)
    rows = [(m[0].queryIdx, m[0].trainIdx, m[0].distance, m[1].distance if len(m) > 1 else 1 << 20)
            for m in knn if len(m) > 0]
    if not rows:
        return empty
    a = np.array(rows)
    good = (a[:, 2] <= max_hamming) & (a[:, 2] < ratio * a[:, 3])
    q, r, d = a[good, 0].astype(np.int64), a[good, 1].astype(np.int64), a[good, 2].astype(np.int64)
    keep = unique_by_reference(q, r, d)
    return q[keep], r[keep]


class _View:
    """Tracking's copy of the local map."""

    def __init__(self, ids=None, pos=None, desc=None):
        self.ids = np.zeros(0, np.int64) if ids is None else np.asarray(ids, np.int64)
        self.pos = np.zeros((0, 3)) if pos is None else np.asarray(pos, float).reshape(-1, 3)
        self.desc = _EMPTY_DESC if desc is None else np.ascontiguousarray(desc, np.uint8).reshape(-1, 32)
        self.words = as_words(self.desc)

    def __len__(self) -> int:
        return len(self.ids)


class MonoTracker:
    """``track(frame) -> TrackingResult``; ``apply_map_update(update)``.

    At initialisation the result carries two keyframes: ``result.keyframes`` lists every
    keyframe to hand to local mapping, in order (``result.keyframe`` is the last one).
    """

    def __init__(self, calib: StereoCalibration, params: TrackingParams | None = None,
                 mono: MonoParams | None = None, initial_pose: np.ndarray | None = None):
        self.calib = calib
        self.params = (params or TrackingParams()).validate()
        self.mono = (mono or MonoParams()).validate()
        if self.mono.n_features:  # the monocular feature count (MonoParams.n_features)
            self.params = replace(self.params, n_features=self.mono.n_features)
        self.extractor = OrbExtractor(self.params)
        self.scale_factors = self.params.scale_factor ** np.arange(self.params.n_levels)
        self.K = calib.K
        self._T_last = np.eye(4) if initial_pose is None else np.asarray(initial_pose, float).copy()
        self._velocity = np.eye(4)
        self._next_landmark_id = 0
        self._view = _View()
        self._segment_start_kf = -1
        self._restart_pending = True
        self.initialised = False
        self.n_lost = 0
        self.n_initialisations = 0
        self._lost_run = 0
        self._init_ref: tuple | None = None       # (frame, features, last matched uv, attempts)
        self._last_matched = (np.zeros((0, 3)), as_words(_EMPTY_DESC), np.zeros(0, np.int64))
        self._ref_kf = -1
        self._T_ref = np.eye(4)
        self._frames_since_kf = 0
        self._tracked_after_kf: int | None = None
        self._seen: list[tuple[np.ndarray, np.ndarray]] = []
        # relocaliser(frame, features) -> (T_world_cam, keyframe, LocalMapUpdate around it) or None:
        # tried on every frame while lost (ORB-SLAM Relocalization; canopy.loop.mono)
        self.relocaliser = None
        self.n_relocalised = 0

    # ------------------------------------------------------------------ map view
    def apply_map_update(self, update: LocalMapUpdate) -> None:
        if update.keyframe_index < self._segment_start_kf or not self.initialised:
            return  # stale: from a map segment before a reset
        self._view = _View(update.landmark_ids, update.positions, update.descriptors)
        if self._ref_kf in update.keyframe_poses:
            T_new = np.asarray(update.keyframe_poses[self._ref_kf], float)
            C = T_new @ se3_inv(self._T_ref)   # local BA moved the reference keyframe
            self._T_ref = T_new
            self._T_last = C @ self._T_last
        # the last frame's matched landmarks move with the bundle-adjusted map
        pos, words, ids = self._last_matched
        if len(ids) and len(self._view):
            order = np.argsort(self._view.ids)
            sorted_ids = self._view.ids[order]
            at = np.clip(np.searchsorted(sorted_ids, ids), 0, len(sorted_ids) - 1)
            hit = sorted_ids[at] == ids
            pos = pos.copy()
            pos[hit] = self._view.pos[order[at[hit]]]
            self._last_matched = (pos, words, ids)

    # ------------------------------------------------------------------ entry point
    def track(self, frame: StereoFrame, fast_threshold: int | None = None, fast_fallback: int | None = None,
              fast_min_keypoints: int = 0) -> MonoTrackingResult:
        t_all = time.perf_counter()
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        feats = self.extractor.extract(frame.left, fast_threshold, fast_fallback, fast_min_keypoints)
        timings["orb"] = _ms(t0)
        if not self.initialised:
            res = self._try_initialise(frame, feats, timings)
        else:
            if self._lost_run > 0 and self.relocaliser is not None:
                t0 = time.perf_counter()
                found = self.relocaliser(frame, feats)
                timings["relocalise"] = _ms(t0)
                if found is not None:
                    self._relocalise_to(*found)
            res = self._track_frame(frame, feats, timings)
        timings["total"] = _ms(t_all)
        res.timings = timings
        return res

    # ------------------------------------------------------------------ initialisation
    def _not_initialised(self, frame: StereoFrame, n_matches: int = 0) -> TrackingResult:
        return MonoTrackingResult(frame.index, frame.timestamp, self._T_last.copy(), STATUS_INIT, 0, n_matches,
                                  False, None, -1)

    def _try_initialise(self, frame: StereoFrame, feats: Features, timings: dict) -> TrackingResult:
        m = self.mono
        if len(feats) < m.init_min_features:
            self._init_ref = None
            return self._not_initialised(frame)
        if self._init_ref is None:
            self._init_ref = (frame, feats, feats.uv.astype(np.float64).copy(), 0)
            return self._not_initialised(frame)
        ref_frame, ref_feats, prev_uv, attempts = self._init_ref
        t0 = time.perf_counter()
        q, r = window_knn(prev_uv, ref_feats.descriptors, feats.uv, feats.descriptors, m.init_search_radius,
                          m.init_max_hamming, m.init_ratio)
        timings["init_match"] = _ms(t0)
        if len(q) < m.init_min_matches or attempts >= m.init_max_frames:
            self._init_ref = (frame, feats, feats.uv.astype(np.float64).copy(), 0)  # a fresh reference
            return self._not_initialised(frame, len(q))
        t0 = time.perf_counter()
        two = initialise_two_view(ref_feats.uv[q], feats.uv[r], self.K, m, seed=self.params.seed + frame.index)
        timings["init_two_view"] = _ms(t0)
        if not two.ok or two.n_good < m.init_min_map_points:
            prev_uv = prev_uv.copy()
            prev_uv[q] = feats.uv[r]
            self._init_ref = (ref_frame, ref_feats, prev_uv, attempts + 1)
            return self._not_initialised(frame, len(q))
        return self._create_initial_map(ref_frame, ref_feats, frame, feats, q[two.good], r[two.good],
                                        two.points_ref[two.good], two.T_cur_ref)

    def _create_initial_map(self, ref_frame, ref_feats, frame, feats, qi, ri, X_ref, T_cur_ref) -> TrackingResult:
        """Two keyframes and the initial landmarks (ORB-SLAM CreateInitialMapMonocular)."""
        T_w_ref = self._T_last.copy()        # a new segment starts where the last one stopped
        T_w_cur = T_w_ref @ se3_inv(T_cur_ref)
        n = len(qi)
        ids = self._next_landmark_id + np.arange(n)
        self._next_landmark_id += n
        depth = np.full(len(ref_feats), -1.0, np.float32)
        depth[qi] = X_ref[:, 2]
        new_ids = np.full(len(ref_feats), -1, np.int64)
        new_ids[qi] = ids
        restart = self._restart_pending
        kf_ref = self._keyframe(ref_frame, ref_feats, T_w_ref, np.full(len(ref_feats), -1, np.int64),
                                restart=restart, depth=depth, new_ids=new_ids)
        matched = np.full(len(feats), -1, np.int64)
        matched[ri] = ids
        X_w = transform(T_w_ref, X_ref)
        self._seen = []
        kf_cur = self._keyframe(frame, feats, T_w_cur, matched)
        self.initialised = True
        self._restart_pending = False
        self._init_ref = None
        self.n_initialisations += 1
        self._segment_start_kf = ref_frame.index
        self._view = _View(ids, X_w, ref_feats.descriptors[qi])
        self._last_matched = (X_w, as_words(feats.descriptors[ri]), ids)
        self._velocity = np.eye(4)
        self._T_last = T_w_cur.copy()
        self._set_reference(frame.index, T_w_cur)
        self._lost_run = 0
        return MonoTrackingResult(frame.index, frame.timestamp, T_w_cur, STATUS_OK, n, n, True, kf_cur, frame.index,
                                  T_ref_cam=np.eye(4), keyframe_reason="initialisation", keyframes=[kf_ref, kf_cur])

    def _keyframe(self, frame, feats: Features, T_wc, matched_ids, restart=False, depth=None,
                  new_ids=None) -> KeyframeData:
        n = len(feats)
        uids, seen_visible, seen_found = seen_counts(self._seen)
        self._seen = []
        return KeyframeData(
            index=frame.index, timestamp=frame.timestamp, T_world_cam=T_wc.copy(),
            uv=feats.uv.astype(np.float32), u_right=np.full(n, -1.0, np.float32),
            depth=np.full(n, -1.0, np.float32) if depth is None else depth,
            descriptors=feats.descriptors.copy(), octave=feats.octave.astype(np.int32),
            landmark_ids=matched_ids.copy(), new_landmark_ids=np.full(n, -1, np.int64) if new_ids is None else new_ids,
            scale_factor=self.params.scale_factor, restart=restart,
            seen_ids=uids, seen_visible=seen_visible, seen_found=seen_found)

    def _set_reference(self, kf_index: int, T_wc: np.ndarray) -> None:
        self._ref_kf = kf_index
        self._T_ref = T_wc.copy()
        self._frames_since_kf = 0
        self._tracked_after_kf = None

    def _relocalise_to(self, T_wc: np.ndarray, kf_index: int, update: LocalMapUpdate) -> None:
        """Back on the map after a relocalisation: the local map around the matched keyframe,
        the pose it gave, no motion; the frame is then tracked as any other."""
        self._view = _View(update.landmark_ids, update.positions, update.descriptors)
        self._last_matched = (np.zeros((0, 3)), as_words(_EMPTY_DESC), np.zeros(0, np.int64))
        self._set_reference(kf_index, np.asarray(update.keyframe_poses[kf_index], float))
        self._T_last = np.asarray(T_wc, float).copy()
        self._velocity = np.eye(4)
        self.n_relocalised += 1

    def _reset(self) -> None:
        """Lost for too long: start a new map segment (ORB-SLAM monocular resets the map)."""
        self.initialised = False
        self._restart_pending = True
        self._init_ref = None
        self._view = _View()
        self._last_matched = (np.zeros((0, 3)), as_words(_EMPTY_DESC), np.zeros(0, np.int64))
        self._velocity = np.eye(4)
        self._lost_run = 0

    # ------------------------------------------------------------------ tracking
    def _sigma(self, octave: np.ndarray) -> np.ndarray:
        return self.params.pixel_sigma * self.scale_factors[octave]

    def _search(self, T_cw, pos, words, feats: Features, kp_words, radius: float, scaled: bool = False):
        proj, Pc = project_stereo(T_cw, pos, self.calib)
        in_view = ((Pc[:, 2] > 0) & (proj[:, 0] >= 0) & (proj[:, 0] < self.calib.width)
                   & (proj[:, 1] >= 0) & (proj[:, 1] < self.calib.height))
        q, r, _ = match_in_window(proj[:, :2], words, np.full(len(pos), radius), feats.uv, kp_words,
                                  self.mono.max_hamming, self.mono.ratio, q_mask=in_view,
                                  r_scale=self.scale_factors[feats.octave] if scaled else None)
        return q, r, in_view

    def _candidates(self, T_pred_cw, feats: Features, kp_words):
        """3D-2D matches for RANSAC: last frame's landmarks, then the local map through the
        prediction, then appearance only (ORB-SLAM TrackReferenceKeyFrame's role)."""
        m = self.mono
        enough = 2 * m.min_inliers
        pos, words, ids = self._last_matched
        best = (np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64))
        for radius in (m.search_radius, m.search_radius_wide):
            q, r, _ = self._search(T_pred_cw, pos, words, feats, kp_words, radius)
            if len(q) > len(best[1]):
                best = (pos[q], r, ids[q])
            if len(best[1]) >= enough:
                return best
        view = self._view
        q, r, _ = self._search(T_pred_cw, view.pos, view.words, feats, kp_words, m.search_radius_wide)
        if len(q) > len(best[1]):
            best = (view.pos[q], r, view.ids[q])
        if len(best[1]) < enough and len(view):
            r2, q2, _ = knn_match(feats.descriptors, view.desc, m.max_hamming, m.ratio)
            if len(q2) > len(best[1]):
                best = (view.pos[q2], r2, view.ids[q2])
        return best

    def _ransac(self, frame_index: int, X: np.ndarray, uv: np.ndarray):
        p = self.params
        if len(X) < self.mono.min_inliers:
            return None
        cv2.setRNGSeed(p.seed + frame_index)
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            np.ascontiguousarray(X, np.float64).reshape(-1, 1, 3), np.ascontiguousarray(uv, np.float64).reshape(-1, 1, 2),
            self.K, None, iterationsCount=p.pnp_iterations, reprojectionError=p.pnp_reprojection_error,
            confidence=p.pnp_confidence, flags=cv2.SOLVEPNP_EPNP)
        if not found or inl is None or len(inl) < self.mono.min_inliers:
            return None
        return pose_from_rvec(rvec, tvec)

    def _refine(self, T_cw, X, r, feats: Features):
        """Motion-only optimisation on monocular reprojection errors (ORB-SLAM PoseOptimization
        with EdgeSE3ProjectXYZOnlyPose): the stereo refiner with no right-image rows."""
        m = self.mono
        meas = np.zeros((len(r), 3))
        meas[:, :2] = feats.uv[r]
        return refine_pose(T_cw, X, meas, np.zeros(len(r), bool), self._sigma(feats.octave[r]), self.calib,
                           m.pose_rounds, m.pose_iterations, m.chi2_mono, m.chi2_mono)

    def _lost(self, frame: StereoFrame, n_inl: int, n_matches: int) -> TrackingResult:
        self.n_lost += 1
        self._lost_run += 1
        self._velocity = np.eye(4)
        self._seen = []
        limit = self.mono.lost_frames_to_reset if self.relocaliser is None else self.mono.reloc_lost_frames_to_reset
        if self._lost_run >= limit:
            self._reset()
        return MonoTrackingResult(frame.index, frame.timestamp, self._T_last.copy(), STATUS_LOST, n_inl, n_matches,
                                  False, None, self._ref_kf)

    def _track_frame(self, frame: StereoFrame, feats: Features, timings: dict) -> TrackingResult:
        m = self.mono
        T_pred_cw = se3_inv(self._T_last @ self._velocity)
        kp_words = as_words(feats.descriptors)
        t0 = time.perf_counter()
        X, r, ids = self._candidates(T_pred_cw, feats, kp_words)
        timings["match_motion"] = _ms(t0)
        t0 = time.perf_counter()
        T_cw = self._ransac(frame.index, X, feats.uv[r]) if len(r) else None
        timings["pnp"] = _ms(t0)
        if T_cw is None:
            return self._lost(frame, 0, len(r))
        t0 = time.perf_counter()
        view = self._view
        q2, r2, in_view = self._search(T_cw, view.pos, view.words, feats, kp_words, m.search_radius_local, scaled=True)
        est = None
        if len(q2) >= m.min_inliers:
            est = self._refine(T_cw, view.pos[q2], r2, feats)
            if int(est.inliers.sum()) >= m.min_inliers:
                X, r, ids = view.pos[q2], r2, view.ids[q2]
            else:
                est = None
        if est is None:
            est = self._refine(T_cw, X, r, feats)
        timings["track_local_map"] = _ms(t0)
        n_inl = int(est.inliers.sum())
        if n_inl < m.min_inliers:
            return self._lost(frame, n_inl, len(r))
        self._lost_run = 0
        T_wc = se3_inv(est.T_cam_world)
        inl = est.inliers
        keep = inl & (ids >= 0)
        self._last_matched = (X[keep].copy(), as_words(feats.descriptors[r[keep]]), ids[keep].copy())
        matched_ids = np.full(len(feats), -1, np.int64)
        matched_ids[r[keep]] = ids[keep]
        visible = view.ids[in_view]
        self._seen.append((visible, np.isin(visible, ids[keep]).astype(np.float64)))

        # keyframe decision (ORB-SLAM NeedNewKeyFrame, monocular)
        self._frames_since_kf += 1
        n_tracked = int(keep.sum())
        if self._tracked_after_kf is None:
            self._tracked_after_kf = n_tracked
        reasons = []
        if self._frames_since_kf >= m.max_frames_between_keyframes:
            reasons.append("max_frames")
        if n_tracked < m.keyframe_tracked_ratio * self._tracked_after_kf:
            reasons.append("tracked_fraction")
        is_kf = (bool(reasons) and self._frames_since_kf >= m.min_frames_between_keyframes
                 and n_tracked > m.keyframe_min_inliers)
        ref = self._ref_kf
        T_ref_cam = se3_inv(self._T_ref) @ T_wc
        kf = None
        if is_kf:
            kf = self._keyframe(frame, feats, T_wc, matched_ids)
            self._set_reference(frame.index, T_wc)
        self._velocity = se3_inv(self._T_last) @ T_wc
        self._T_last = T_wc.copy()
        return MonoTrackingResult(frame.index, frame.timestamp, T_wc, STATUS_OK, n_inl, len(r), is_kf, kf, ref,
                                  T_ref_cam=T_ref_cam, keyframe_reason="+".join(reasons) if is_kf else "",
                                  keyframes=[kf] if kf is not None else [])
