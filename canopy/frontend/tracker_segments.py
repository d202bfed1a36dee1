"""Map segments of the stereo tracker: (re)initialisation from one stereo frame, the keyframe payload
sent to local mapping, and frames without a trusted pose (bridged by the motion model, then lost).

A mixin of ``canopy.frontend.tracker.Tracker`` (split out of it by responsibility); it reads and writes
the tracker's state (``_T_last``, ``_velocity``, ``_provisional``, ``_ref_kf`` ...) set up there.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from canopy.frontend.features import Features
from canopy.frontend.geometry import se3_inv
from canopy.frontend.map_view import seen_counts
from canopy.frontend.matching import as_words
from canopy.frontend.messages import KeyframeData, TrackingResult
from canopy.frontend.stereo import StereoMatches
from canopy.frontend.track_health import LOST_TOO_FEW_STEREO
from canopy.frontend.tracker_vertical import keyframe_vertical
from canopy.frontend.vertical_gate import gate_keyframe_up, noisy_enough
from shared.arrays import unique_sorted
from shared.types import StereoFrame

if TYPE_CHECKING:
    from canopy.frontend.line_tracking import LineFrame

STATUS_INIT, STATUS_OK, STATUS_LOST = "init", "ok", "lost"
STATUS_PREDICTED = "predicted"  # no trusted pose: the motion model's, bridging a short gap (lost_reason says why)


class TrackerSegmentsMixin:
    # ------------------------------------------------------------------ (re)initialisation
    def _initialise(self, frame: StereoFrame, feats: Features, stereo: StereoMatches, n_stereo: int,
                    lines: LineFrame | None = None) -> TrackingResult:
        T_wc = self._T_last.copy()  # first frame: initial pose; restart: last good pose
        if n_stereo < self.params.min_init_points:
            self.n_lost += 1
            if self._initialised:
                self._lost_streak += 1
            return TrackingResult(frame.index, frame.timestamp, T_wc, STATUS_LOST, 0, 0, False, None,
                                  self._ref_kf, lost_reason=LOST_TOO_FEW_STEREO)
        restart = True
        self._initialised = True
        self._need_restart = False
        self._lost_streak = 0
        self._velocity = np.eye(4)
        self._velocity_valid = False
        self._n_failed = 0
        # a new map segment: forget the old view (its landmarks are not connected to this one)
        self._update_view.set(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 32), np.uint8))
        self._provisional.clear()
        self._segment_start_kf = frame.index
        self._last_matched = (np.zeros((0, 3)), as_words(np.zeros((0, 32), np.uint8)), np.zeros(0, np.int64))
        if self._lines_on:
            self._line_update_view.set(np.zeros(0, np.int64), np.zeros((0, 2, 3)), np.zeros((0, 32), np.uint8))
            self._line_provisional.clear()
            self._line_view_dirty = True
        matched_ids = np.full(len(feats), -1, np.int64)
        line_matched = None if lines is None else np.full(len(lines), -1, np.int64)
        kf = self._make_keyframe(frame, feats, stereo, T_wc, matched_ids, restart=restart, lines=lines,
                                 line_matched=line_matched)
        ids, pos, desc = self._provisional[frame.index]
        self._last_matched = (pos, as_words(desc), ids)
        self._after_frame(T_wc, feats, stereo)
        return TrackingResult(frame.index, frame.timestamp, T_wc, STATUS_INIT, int((kf.new_landmark_ids >= 0).sum()),
                              0, True, kf, frame.index, T_ref_cam=np.eye(4))

    def _make_keyframe(self, frame, feats, stereo, T_wc, matched_ids, restart=False, lines=None,
                       line_matched=None) -> KeyframeData:
        """Build the keyframe payload; reserve ids for new close stereo landmarks."""
        new_ids = np.full(len(feats), -1, np.int64)
        create = self._landmark_candidates(stereo) & (matched_ids < 0)
        idx = np.flatnonzero(create)
        new_ids[idx] = self._next_landmark_id + np.arange(len(idx))
        self._next_landmark_id += len(idx)
        pos = self._stereo_points_world(feats, stereo, T_wc, idx)
        self._record_viewing(new_ids[idx], pos, T_wc[:3, 3], feats.octave[idx])
        self._provisional[frame.index] = (new_ids[idx], pos, feats.descriptors[idx])
        self._view_dirty = True
        uids, seen_visible, seen_found = seen_counts(self._seen)
        self._seen = []
        line_fields = {} if lines is None else self._keyframe_lines(frame, lines, line_matched, T_wc)
        kf = KeyframeData(
            index=frame.index, timestamp=frame.timestamp, T_world_cam=T_wc.copy(),
            uv=feats.uv.astype(np.float32), u_right=self._keyframe_u_right(stereo),
            depth=stereo.depth.astype(np.float32), descriptors=feats.descriptors.copy(),
            octave=feats.octave.astype(np.int32), landmark_ids=matched_ids.copy(), new_landmark_ids=new_ids,
            scale_factor=self.params.scale_factor, restart=restart,
            seen_ids=uids, seen_visible=seen_visible, seen_found=seen_found, **line_fields)
        if self.params.vertical_estimate and restart:
            keyframe_vertical(self).restart()   # a new segment: its own reference, gated keyframe or not
        # the keyframe's measured up (tracker_vertical); tracking.vertical_min_sensor_sigma: on noisy frames only
        if self.params.vertical_estimate and noisy_enough(getattr(self, "_frame_sensor_sigma", None),
                                                          self.params.vertical_min_sensor_sigma):
            vert = keyframe_vertical(self)
            kf.up_cam, kf.up_sigma_deg = vert.measure(frame.left, T_wc, frame.index)
            # tracking.vertical_gate_ratio: only where the keyframe's points hold pitch/roll weakly
            kf.up_cam, kf.up_sigma_deg = gate_keyframe_up(self, feats, stereo, T_wc, matched_ids, kf.up_cam,
                                                          kf.up_sigma_deg, vert.gate_history)
        self._remember_keyframe(kf)
        self._ref_kf = frame.index
        self._T_ref = T_wc.copy()
        # sorted distinct ids by a sort: numpy's plain np.unique hashes, 20-50x slower here (shared.arrays)
        self._ref_ids = unique_sorted(np.concatenate([matched_ids[matched_ids >= 0], new_ids[idx]]))
        self._frames_since_kf = 0
        self._entropy_first = None
        self._ref_tracked_first = None
        return kf

    def _not_tracked(self, frame: StereoFrame, reason: str, n_inliers: int, n_matches: int) -> TrackingResult:
        """A frame without a trusted pose. Within ``max_predicted_frames`` of the last tracked frame
        the constant-velocity prediction bridges the gap (status "predicted", the map is kept);
        after that the frame is lost and the next one restarts a map segment."""
        self._n_failed += 1
        if self._n_failed <= self.params.max_predicted_frames:
            self.n_predicted += 1
            self._T_last = self._T_last @ self._velocity
            return TrackingResult(frame.index, frame.timestamp, self._T_last.copy(), STATUS_PREDICTED, n_inliers,
                                  n_matches, False, None, self._ref_kf, T_ref_cam=se3_inv(self._T_ref) @ self._T_last,
                                  lost_reason=reason)
        self.n_lost += 1
        self._need_restart = True
        if self._lost_streak == 0:  # first lost frame: keep the motion for the relocalisation bridge
            self._bridge_velocity = self._velocity.copy()
            self._lost_streak = 1
        self._velocity = np.eye(4)
        self._velocity_valid = False
        self._seen = []
        return TrackingResult(frame.index, frame.timestamp, self._T_last.copy(), STATUS_LOST, n_inliers, n_matches,
                              False, None, self._ref_kf, lost_reason=reason)
