"""Stereo tracking (AGRI §3.2): ORB on both images, stereo matching, temporal matching
against the local-map view, EPnP RANSAC + motion-only refinement, entropy-ratio keyframes.

``Tracker`` is process-free: ``track(frame)`` consumes one StereoFrame and returns a
``TrackingResult`` (with a ``KeyframeData`` payload when a keyframe is chosen);
``apply_map_update(update)`` feeds the local map computed by local mapping back in.

Where things are:
* the landmark store tracking reads: ``Tracker._map_view()`` -> ``canopy.frontend.map_view.MapView``
  (last ``LocalMapUpdate`` in ``_update_view`` + provisional landmarks of unacknowledged
  keyframes in ``_provisional``); ``apply_map_update``: ``canopy.frontend.tracker_map_view``;
* ORB on both images and stereo matching, the right image on a worker thread while this one
  searches the local map (``parallel_stereo``): ``canopy.frontend.tracker_worker``; the
  frame's stereo matches are taken with ``Tracker._stereo`` (waits for the worker if needed);
* pose solving (projection search, EPnP RANSAC, motion-only refinement):
  ``canopy.frontend.map_tracking.MapTrackingMixin``;
* the keyframe policy (AGRI Eq. 6-7 and ORB-SLAM's conditions): ``canopy.frontend.keyframe_policy``;
* trust in a pose, lost reasons, the noise-scaled FAST threshold: ``canopy.frontend.track_health``;
* line features: ``canopy.frontend.tracker_lines.TrackerLinesMixin``;
* map segments: (re)initialisation, the keyframe payload, frames without a trusted pose (predicted /
  lost): ``canopy.frontend.tracker_segments.TrackerSegmentsMixin``;
* far points as bearing-only measurements, the frustum test of the local-map search:
  ``canopy.frontend.tracker_measurements.TrackerMeasurementsMixin``.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from canopy.frontend.noisy_features import tracking_extractor
from canopy.frontend.features import Features
from canopy.frontend.keyframe_policy import entropy_ratio, keyframe_reasons
from canopy.frontend.geometry import (differential_entropy, pose_information, se3_inv, stereo_pose_jacobian,
                                      transform)
from canopy.frontend.map_tracking import MapTrackingMixin
from canopy.frontend.map_view import MapView
from canopy.frontend.tracker_map_view import TrackerMapViewMixin
from canopy.frontend.matching import as_words
from canopy.frontend.motion_check import ransac_or_prediction
from canopy.frontend.messages import TrackingResult
from canopy.frontend.params import TrackingParams
from canopy.frontend.pose import MotionPrior
from canopy.frontend.travel_direction import TravelDirection, texture_gate_open, travel_direction_term
from canopy.frontend.stereo import StereoMatches
from canopy.frontend.step_check import local_map_pose, recheck_step
from canopy.frontend.track_health import LOST_TOO_FEW_MATCHES, image_noise_sigma, judge_pose
from canopy.frontend.tracker_lines import TrackerLinesMixin
from canopy.frontend.tracker_measurements import TrackerMeasurementsMixin
from canopy.frontend.tracker_reloc import TrackerRelocalisationMixin
from canopy.frontend.tracker_vertical import frame_attitude_term
from canopy.frontend.tracker_segments import STATUS_LOST, STATUS_OK, TrackerSegmentsMixin
from canopy.frontend.tracker_worker import (ExtractedFrame, StereoJob, TrackerFeaturesMixin, record_stage as _stage,
                                           stage_clock as _clock)
from shared.arrays import isin_ids
from shared.types import StereoCalibration, StereoFrame

if TYPE_CHECKING:
    from canopy.frontend.line_tracking import LineFrame

LINE_REJECT_REASONS = ("nan", "zero_length", "outside", "short")  # canopy.lines.detect_segments stats


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


class Tracker(TrackerMapViewMixin, TrackerFeaturesMixin, TrackerMeasurementsMixin, MapTrackingMixin, TrackerLinesMixin,
              TrackerRelocalisationMixin, TrackerSegmentsMixin):
    def __init__(self, calib: StereoCalibration, params: TrackingParams | None = None,
                 initial_pose: np.ndarray | None = None):
        self.calib = calib
        self.params = (params or TrackingParams()).validate()
        # tracking.extractor: opencv | cells. Nothing in tracking, mapping or loop closing reads the
        # keypoints' responses (stereo matching, the map searches and the keyframes use positions,
        # octaves and descriptors), so the cells extractor skips its Harris responses (~3 ms per
        # KITTI image; its ranking "fast" does not need them)
        self.extractor = tracking_extractor(self.params, responses=False)
        # cv2.ORB objects are not thread-safe: the right image gets its own extractor.
        self.extractor_right = tracking_extractor(self.params, responses=False)
        self._pool = ThreadPoolExecutor(max_workers=1) if self.params.parallel_extraction else None
        # the right image's ORB and the stereo matching in that worker while this thread searches the
        # local map (canopy.frontend.tracker_worker); lines keep their own jobs in it, so not with lines
        self._parallel_stereo = bool(self.params.parallel_stereo and self._pool is not None and not self.params.use_lines)
        self.scale_factors = self.params.scale_factor ** np.arange(self.params.n_levels)
        self.K = calib.K
        self._initial_pose = np.eye(4) if initial_pose is None else np.asarray(initial_pose, float)
        self._max_depth = self.params.max_depth_baselines * calib.baseline
        self._close_depth = self.params.close_depth_baselines * calib.baseline
        # ORB-SLAM's ThDepth role for measurements: beyond it a stereo point's depth is too noisy
        # (and sub-pixel disparities biased) to measure translation; bearing only
        self._stereo_obs_depth = (self.params.stereo_obs_max_depth_baselines * calib.baseline
                                  if self.params.stereo_obs_max_depth_baselines > 0 else np.inf)
        # ... and on noisy frames (tracking.noisy_stereo_obs_max_depth_baselines; tracker_measurements._noisy_far)
        self._noisy_stereo_obs_depth = (self.params.noisy_stereo_obs_max_depth_baselines * calib.baseline
                                        if self.params.noisy_stereo_obs_max_depth_baselines > 0 else np.inf)
        # map view = last update + provisional landmarks of keyframes not yet acknowledged
        self._update_view = MapView()
        self._provisional: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._view = MapView()
        self._view_dirty = False
        self._next_landmark_id = 0
        # ORB-SLAM's viewing direction and scale-invariance distance of each landmark this tracker
        # created (indexed by id; 0 distance: unknown), for the frustum test of the local-map search
        self._lm_normal = np.zeros((0, 3))
        self._lm_max_dist = np.zeros(0)
        self._stereo_last = self._stereo_obs = self._stereo_raw = None
        self._contour_inputs = None
        self._silhouette = self._make_silhouette_detector()  # tracking.contour_* (None: off)
        self._segment_start_kf = -1
        # motion state
        self._initialised = False
        self._need_restart = False
        self._lost_streak = 0                       # frames lost in a row (relocalisation bridge)
        self._bridge_velocity = np.eye(4)           # per-frame motion when tracking was lost
        self._T_last = self._initial_pose.copy()    # T_world_cam of the last good frame
        self._velocity = np.eye(4)                  # T_last-1_last (constant-velocity model)
        self._last_points_w: np.ndarray | None = None  # last frame's stereo points (fallback)
        self._loop_epoch_seen = 0  # loop corrections of the map seen in updates (LocalMapUpdate.loop_epoch)
        self._last_words: np.ndarray | None = None
        self._last_matched = (np.zeros((0, 3)), as_words(np.zeros((0, 32), np.uint8)), np.zeros(0, np.int64))
        # keyframe state
        self._ref_kf = -1
        self._T_ref = np.eye(4)
        self._ref_ids = np.zeros(0, np.int64)
        self._frames_since_kf = 0
        self._entropy_first: float | None = None
        self._ref_tracked_first: int | None = None
        self._seen: list[tuple[np.ndarray, np.ndarray]] = []
        self.n_lost = 0
        self.n_predicted = 0
        self._n_failed = 0            # consecutive frames without a trusted pose
        self._velocity_valid = False  # the constant-velocity model has seen two tracked frames
        # the rig's direction of travel in its camera frame: a property of the rig, kept across map segments
        self._travel = TravelDirection(self.params.travel_direction_window, self.params.travel_direction_min_steps,
                                       self.params.travel_direction_min_step_m)
        # line features (issue 4), all inert unless params.use_lines
        self._lines_on = bool(self.params.use_lines)
        if self._lines_on:
            # imported here: canopy.lines builds on canopy.frontend.geometry, so a module-level
            # import would make the two packages import each other
            from canopy.frontend import line_tracking
            from canopy.lines import (LineDescriber, LineParams, detect_segments, match_stereo_lines,
                                      right_segments_in_reach)
            self._lt = line_tracking
            self._detect_segments, self._match_stereo_lines = detect_segments, match_stereo_lines
            self._right_in_reach = right_segments_in_reach
            p = self.params
            self.line_params = LineParams(detector=p.line_detector, max_lines=p.line_max_lines,
                                          min_length_fraction=p.line_min_length_fraction)
            # one describer per thread: the left image is described in the worker
            self._line_describer = LineDescriber(self.line_params)
            self._line_describer_right = LineDescriber(self.line_params)
            # line jobs queue behind the right image's ORB in its worker (one FIFO thread: with
            # two cores, ORB left | ORB right, then lines while the main thread matches stereo)
            self._line_pool = self._pool if self._pool is not None else ThreadPoolExecutor(max_workers=1)
            self._right_lines_job = None      # (frame index, future) of the right image's lines
            self._line_timings: dict[str, float] = {}
            self._last_was_keyframe = False
            self._line_update_view = line_tracking.LineMapView()
            self._line_provisional: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
            self._line_view = line_tracking.LineMapView()
            self._line_view_dirty = False
            self._next_line_id = 0
            self._ref_line_ids = np.zeros(0, np.int64)
            self._line_max_depth = p.line_max_depth_baselines * calib.baseline

    def worker_thread_id(self) -> int | None:
        """The worker thread's OS id (for per-thread CPU statistics), None without a worker."""
        return None if self._pool is None else self._pool.submit(threading.get_native_id).result()

    # ------------------------------------------------------------------ map view
    # ------------------------------------------------------------------ helpers
    def _sigma(self, octave: np.ndarray) -> np.ndarray:
        return self.params.pixel_sigma * self.scale_factors[octave]

    # ------------------------------------------------------------------ main entry
    def track(self, frame: StereoFrame, fast_threshold: int | None = None,
              fast_fallback: int | None = None, fast_min_keypoints: int = 0,
              sensor_sigma: float | None = None) -> TrackingResult:
        """Track one stereo frame. ``fast_threshold`` / ``fast_fallback`` override the
        FAST threshold (AFE Eq. 18 / Eq. 19 when too few of ``fast_min_keypoints``); ``sensor_sigma``:
        the enhancement's noise sigma of the frame (its ``info["noise_sigma"]``; None: not handed over),
        for the fill-in gate of enhanced frames (``stereo_fill.sensor_fill_open``)."""
        return self.track_extracted(self.extract(frame, fast_threshold, fast_fallback, fast_min_keypoints,
                                                 sensor_sigma))

    def extract(self, frame: StereoFrame, fast_threshold: int | None = None,
                fast_fallback: int | None = None, fast_min_keypoints: int = 0,
                sensor_sigma: float | None = None) -> ExtractedFrame:
        """The first half of ``track``: the frame's noise, its left ORB features (this thread) and
        its stereo matches (with ``parallel_stereo`` a job left running on the worker). None of it
        reads the local map, so a lockstep run may call this before applying the map updates due
        at this frame (``apply_map_update``) and ``track_extracted`` after: the same result as
        ``track`` with the updates applied first (the extraction overlaps local mapping's BA
        instead of waiting for it; ``actors.tracking``)."""
        timings: dict[str, float] = {}
        t_all = t0 = _clock()
        self._stereo_last = self._stereo_raw = None
        noise_sigma = self._frame_noise_sigma = None
        self._frame_sensor_sigma = sensor_sigma
        if self.params.fast_noise_factor > 0:
            # FAST threshold floor from the image noise (track_health): corners from the signal
            noise_sigma = self._frame_noise_sigma = image_noise_sigma(frame.left)
            floor = int(round(self.params.fast_noise_factor * noise_sigma))
            base = self.params.fast_threshold if fast_threshold is None else int(fast_threshold)
            if floor > base:
                fast_threshold = min(floor, 254)
                if fast_fallback is not None:
                    fast_fallback = max(int(fast_fallback), min(floor, 254) // 2)
            _stage(timings, "noise_estimate", t0)
        left, stereo, line_job = self._left_and_stereo(frame, (fast_threshold, fast_fallback, fast_min_keypoints),
                                                       noise_sigma, timings, sensor_sigma)
        self._contour_inputs = (frame.left, frame.right, left)  # for _stereo's contour test
        return ExtractedFrame(frame, left, stereo, line_job, noise_sigma, timings, t_all)

    def track_extracted(self, ex: ExtractedFrame, paused_s: float = 0.0) -> TrackingResult:
        """The second half of ``track`` (the pose against the local map, the keyframe decision) for
        the frame ``extract`` returned last. ``paused_s``: wall time spent between the two halves on
        something else (waiting for a map update), left out of the ``total`` stage."""
        frame, left, stereo, line_job, noise_sigma, timings = (ex.frame, ex.left, ex.stereo, ex.line_job,
                                                               ex.noise_sigma, ex.timings)
        if not isinstance(stereo, StereoJob):
            stereo = self._stereo(stereo, timings)
        lines = None
        if line_job is not None:
            t0 = time.perf_counter()
            lines = line_job.result()
            timings["lines_wait"] = _ms(t0)  # what the worker's detection + LBD cost beyond ORB/stereo
            timings["lines_detect_worker"] = lines.stats["detect_ms"]
            timings["lines_describe_worker"] = lines.stats["describe_ms"]
        if self._need_restart and 0 < self._lost_streak <= self.params.relocalise_bridge_frames:
            res = self._relocalise(frame, left, stereo, timings, lines)
        elif self._db_reloc_due():  # after the bridge, or the start in a loaded map (tracker_reloc)
            res = self._relocalise_by_query(frame, left, self._stereo(stereo, timings))
        elif not self._initialised or self._need_restart:
            stereo = self._stereo(stereo, timings)
            res = self._initialise(frame, left, stereo, int(stereo.valid.sum()), lines)
        else:  # with parallel_stereo the search against the local map runs before the matches are in
            res = self._track_frame(frame, left, stereo, timings, lines)
        res.n_stereo = int(self._stereo(stereo, timings).valid.sum())
        res.noise_sigma = noise_sigma
        if self._lines_on:
            self._finish_line_jobs(res.is_keyframe)
            timings.update(self._line_timings)
            self._line_timings.clear()
        _stage(timings, "total", ex.t_all)
        timings["total"] -= paused_s * 1e3
        res.timings = timings
        return res

    # ------------------------------------------------------------------ relocalisation
    def _relocalise(self, frame: StereoFrame, feats: Features, stereo: StereoMatches, timings,
                    lines: LineFrame | None = None) -> TrackingResult:
        """Track a frame after a loss against the same local map: the motion model bridges the
        lost frames (prediction T_last V^(k+1) after k lost frames), and ``_track_frame`` falls
        back to appearance matching against the map view when the prediction finds too little.
        Success joins the existing map (no new segment)."""
        k = self._lost_streak
        self._velocity = np.linalg.matrix_power(self._bridge_velocity, k + 1)
        self._need_restart = False
        res = self._track_frame(frame, feats, stereo, timings, lines)
        if res.status == STATUS_LOST:
            self._lost_streak = k + 1  # _track_frame asked for a restart again
            return res
        self._lost_streak = 0
        self._velocity = self._bridge_velocity.copy()
        res.keyframe_reason = "+".join(filter(None, [res.keyframe_reason, "relocalised"]))
        return res

    def _after_frame(self, T_wc, feats: Features, stereo: StereoMatches) -> None:
        self._velocity = se3_inv(self._T_last) @ T_wc
        self._T_last = T_wc.copy()
        idx = np.flatnonzero(stereo.valid)
        self._last_points_w = self._stereo_points_world(feats, stereo, T_wc, idx)
        self._last_words = as_words(feats.descriptors[idx])

    def _track_frame(self, frame: StereoFrame, feats: Features, stereo: StereoMatches, timings,
                     lines: LineFrame | None = None) -> TrackingResult:
        p = self.params
        T_pred_cw = se3_inv(self._T_last @ self._velocity)  # constant-velocity prediction
        self._motion_prior = None  # tracking.motion_prior_sigma_*: the prediction as a pose prior
        # (not after a gap: a bridged prediction T_last V^(k+1) has no per-frame sigma)
        if ((p.motion_prior_sigma_deg > 0 or p.motion_prior_sigma_m > 0) and self._velocity_valid
                and self._n_failed == 0 and self._lost_streak == 0):
            var = None
            if p.motion_prior_pose_var_factor > 0 and getattr(self, "_prior_pose_var", None) is not None:
                var = p.motion_prior_pose_var_factor * self._prior_pose_var
            self._motion_prior = MotionPrior(T_pred_cw, np.radians(p.motion_prior_sigma_deg), p.motion_prior_sigma_m,
                                             pose_variance=var)
        # tracking.vertical_track_prior: the frame's measured up as a prior on its pitch and roll (tracker_vertical)
        self._attitude_term = frame_attitude_term(self, frame, T_pred_cw) if p.vertical_track_prior else None
        # tracking.travel_direction_sigma_deg: the step follows the rig's direction of travel (travel_direction)
        # (a step of one frame from a tracked one: not after a gap, whose T_last is older)
        one_step = self._velocity_valid and self._n_failed == 0 and self._lost_streak == 0
        self._travel_term = None
        if (p.travel_direction_sigma_deg > 0 and one_step
                and texture_gate_open(feats.robust_noise_sigma, getattr(self, "_frame_noise_sigma", None),
                                      p.travel_direction_max_texture)):
            self._travel_term = travel_direction_term(self._travel, self._T_last, self._velocity,
                                                      p.travel_direction_sigma_deg)
        kp_words = as_words(feats.descriptors)
        view = self._map_view()

        t0 = _clock()
        X, r, ids, words = self._initial_matches(T_pred_cw, view, feats, kp_words)
        _stage(timings, "match_motion", t0)
        t0 = _clock()
        T_cw, inliers = self._ransac(frame.index, X, feats.uv[r])
        if T_cw is None and not self._velocity_valid and p.appearance_retry:
            # the window matches came through a prediction that cannot be trusted (the frame after
            # (re)initialisation: no velocity yet, the car moved 1.2 m): try appearance matches
            X2, r2, ids2, words2 = self._appearance_matches(view, feats)
            T2, inl2 = self._ransac(frame.index, X2, feats.uv[r2])
            if T2 is not None:
                T_cw, inliers, X, r, ids, words = T2, inl2, X2, r2, ids2, words2
        _stage(timings, "pnp", t0)
        lview = self._line_map_view() if lines is not None else None
        from_prediction = False
        if p.ransac_max_deviation_deg > 0 or p.ransac_max_deviation_m > 0:  # canopy.frontend.motion_check
            T_cw, inliers, from_prediction = ransac_or_prediction(self, T_cw, inliers, T_pred_cw, X, r, feats)
        if T_cw is None and p.track_from_prediction and self._velocity_valid:  # ORB-SLAM's TrackWithMotionModel
            T_cw, inliers, from_prediction = self._start_from_prediction(T_pred_cw, X, feats.uv[r], inliers)
        if T_cw is None and lview is not None and len(lview):
            # too few points for RANSAC: start from the constant-velocity prediction and let the
            # line terms carry the pose (robust rounds sort out the stage-1 point outliers)
            T_cw, inliers, from_prediction = T_pred_cw, np.ones(len(X), bool), True

        t0 = _clock()
        est = None
        visible_ids = np.zeros(0, np.int64)
        line_obs = lq = lr = None
        if T_cw is not None:
            n_lines = 0
            if lview is not None:
                t1 = time.perf_counter()
                radius = p.line_search_radius_wide if from_prediction else p.line_search_radius
                lq, lr, _ = self._lt.match_map_lines(T_cw, lview, lines, self.calib, radius, p.line_max_angle_deg,
                                            p.line_max_hamming, p.line_ratio)
                line_obs = (lview.A[lq], lview.B[lq], lines.coeffs[lr])
                n_lines = p.line_weight_in_count * len(lq)
                timings["line_match"] = _ms(t1)
            if from_prediction:
                # refine on lines + stage-1 points first, then search the local map from there
                stereo = self._stereo(stereo, timings)
                est = self._refine(T_cw, X, r, feats, stereo, inliers=inliers, line_obs=line_obs)
                T_cw = est.T_cam_world
                est = None
            # stage 2 (TrackLocalMap): all local-map points through the RANSAC pose, small window;
            # the worker's stereo matches are waited for after the search (canopy.frontend.step_check)
            stereo_of, stage1 = (lambda: self._stereo(stereo, timings)), (X, r, ids, words)
            solved = local_map_pose(self, T_cw, view, feats, kp_words, stereo_of, stage1, inliers, line_obs, n_lines)
            if (p.step_max_deviation_m > 0 and lview is None and not from_prediction and self._velocity_valid
                    and self._n_failed == 0 and self._lost_streak == 0):  # a step the motion model cannot explain
                solved = recheck_step(self, solved, T_pred_cw, view, feats, kp_words, stereo_of, stage1, inliers)
            est, (X, r, ids, words), visible_ids = solved
        stereo = self._stereo(stereo, timings)
        _stage(timings, "track_local_map", t0)  # includes the wait for the worker's stereo (its own stage)
        n_matches = len(r)
        if est is None:
            reason = LOST_TOO_FEW_MATCHES
        else:
            reason = judge_pose(self._n_support(est), n_matches + (len(lq) if lq is not None else 0),
                                est.T_cam_world, T_pred_cw, p, check_motion=self._velocity_valid)
        if reason:
            return self._not_tracked(frame, reason, 0 if est is None else int(est.inliers.sum()), n_matches)
        self._n_failed = 0
        T_cw, inliers, info = est.T_cam_world, est.inliers, est.information
        if p.motion_prior_pose_var_factor > 0:  # this pose's variances, for the next frame's prior
            try:
                self._prior_pose_var = np.clip(np.diag(np.linalg.inv(info)), 0.0, None)
            except np.linalg.LinAlgError:
                self._prior_pose_var = None
        line_matched = ref_lines = None
        if lines is not None:
            linl = est.line_inliers
            line_matched = np.full(len(lines), -1, np.int64)
            line_matched[lr[linl]] = lview.ids[lq[linl]]
            ref_lines = linl & isin_ids(lview.ids[lq], self._ref_line_ids)

        T_wc = se3_inv(T_cw)
        n_inl = int(inliers.sum())
        keep = inliers & (ids >= 0)
        self._last_matched = (X[keep].copy(), words[keep].copy(), ids[keep].copy())
        matched_ids = np.full(len(feats), -1, np.int64)
        good = inliers & (ids >= 0)
        matched_ids[r[good]] = ids[good]
        found_mask = isin_ids(visible_ids, matched_ids[matched_ids >= 0])  # np.isin's booleans, by a table
        self._seen.append((visible_ids, found_mask.astype(np.float64)))

        # ---- keyframe decision (AGRI §3.2.4, Eq. 6-7 after Kerl et al. 2013) ----
        t0 = _clock()
        self._frames_since_kf += 1
        from_ref = inliers & isin_ids(ids, self._ref_ids)
        n_ref = int(from_ref.sum())
        if ref_lines is not None:  # the keyframe's own lines constrain the motion too
            n_ref += p.line_weight_in_count * int(ref_lines.sum())
        entropy = None
        if n_ref >= p.min_inliers:
            # uncertainty of the motion relative to the last keyframe: the pose information
            # carried by the keyframe's own landmarks (DVO-SLAM: frame-to-keyframe alignment)
            meas_ref = from_ref[inliers]
            Pc_all = transform(T_cw, X[inliers])
            J = stereo_pose_jacobian(Pc_all[meas_ref], self.calib)
            info_ref = pose_information(J, self._sigma(feats.octave[r[inliers]][meas_ref]), stereo.valid[r[inliers]][meas_ref])
            if ref_lines is not None and ref_lines.any():
                info_ref = info_ref + self._lt.line_information(T_cw, line_obs[0][ref_lines], line_obs[1][ref_lines],
                                                       line_obs[2][ref_lines], p.line_sigma, self.calib)
            try:
                entropy = differential_entropy(np.linalg.inv(info_ref))
            except np.linalg.LinAlgError:
                entropy = None
        if self._frames_since_kf == 1:
            self._entropy_first = entropy
            self._ref_tracked_first = n_ref
        ratio = entropy_ratio(entropy, self._entropy_first)
        close = self._close(stereo)
        n_tracked_close = int((close[r] & inliers).sum())
        n_new_close = int(close.sum()) - n_tracked_close
        since = self._frames_since_kf
        reasons = keyframe_reasons(p, since, ratio, n_ref, self._ref_tracked_first, n_tracked_close, n_new_close)
        need = bool(reasons)
        is_kf = need and since >= p.min_frames_between_keyframes
        if is_kf and self._localize:  # localisation only: move in the loaded map, never add to it
            self._switch_reference(matched_ids)
            is_kf = False
        kf = self._make_keyframe(frame, feats, stereo, T_wc, matched_ids, lines=lines,
                                 line_matched=line_matched) if is_kf else None
        _stage(timings, "keyframe", t0)
        ref = self._ref_kf
        T_ref_cam = se3_inv(self._T_ref) @ T_wc
        self._after_frame(T_wc, feats, stereo)
        if one_step and p.travel_direction_sigma_deg > 0:
            self._travel.add(self._velocity)
        self._velocity_valid = True
        full_cov = None
        if info is not None:
            try:
                full_cov = np.linalg.inv(info)
            except np.linalg.LinAlgError:
                full_cov = None
        res = TrackingResult(frame.index, frame.timestamp, T_wc, STATUS_OK, n_inl, n_matches, is_kf, kf, ref,
                             pose_covariance=full_cov, entropy=entropy, entropy_ratio=ratio,
                             T_ref_cam=T_ref_cam, keyframe_reason="+".join(reasons) if is_kf else "")
        if lines is not None:
            res.n_lines = len(lines)
            res.n_line_matches = len(lq)
            res.n_line_inliers = int(est.line_inliers.sum())
            res.line_rejected = {k: int(lines.stats.get(k, 0)) for k in LINE_REJECT_REASONS}
        return res
