"""Tracking's side of relocalisation by database query and of localisation in a loaded map.

A mixin of ``canopy.frontend.Tracker`` (uses its map view, reference keyframe and motion
state). With a ``PlaceMemory`` attached (``attach_place_memory``):

* ``live``: the memory fills with the tracker's own keyframes and the local-map updates; when
  the motion-model bridge (``_relocalise``) has run out, each new frame queries the database
  (``PlaceMemory.relocalise``) for up to ``LoopParams.reloc_max_frames`` frames before a new
  map segment is started; a frame found joins the existing map (same landmarks, same segment).
* a loaded map (``--load-map``): the first frames are relocalised against it the same way
  (not by the motion model: nothing is known of where the camera starts). With ``localize``
  no keyframe is made: when the keyframe policy would make one, tracking moves its reference
  to the map keyframe sharing most landmarks with the frame and its local map to that
  keyframe's covisible keyframes (ORB-SLAM's localisation mode), so the map never changes.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import as_words
from canopy.frontend.messages import TrackingResult
from shared.arrays import unique_sorted

LOST_NOT_RELOCALISED = "not_relocalised"   # no map keyframe recognised and verified yet


class TrackerRelocalisationMixin:
    _place = None            # PlaceMemory or None
    _place_live = False      # filled from this run's keyframes
    _localize = False        # a loaded map, tracked without making keyframes
    _awaiting_map = False    # a loaded map the first frame has not been found in yet
    n_db_relocalised = 0

    def attach_place_memory(self, memory, live: bool = True, loaded: bool = False, localize: bool = False) -> None:
        self._place = memory
        self._place_live = bool(live)
        self._localize = bool(localize)
        self._awaiting_map = bool(loaded)
        if loaded:  # new landmarks of an extending run must not take a loaded landmark's id
            self._next_landmark_id = max(self._next_landmark_id, memory.max_landmark_id() + 1)

    def _db_reloc_due(self) -> bool:
        if self._place is None:
            return False
        if self._awaiting_map:
            return True
        if not self._need_restart:
            return False
        bridge = self.params.relocalise_bridge_frames
        return self._localize or self._lost_streak <= bridge + self._place.params.reloc_max_frames

    # ------------------------------------------------------------------ memory upkeep
    def _remember_keyframe(self, kf) -> None:
        if self._place is None or not self._place_live:
            return
        ids = np.where(kf.landmark_ids >= 0, kf.landmark_ids, kf.new_landmark_ids)
        self._place.add_keyframe(kf.index, kf.timestamp, kf.T_world_cam, kf.uv, kf.u_right, kf.depth, kf.octave,
                                 kf.descriptors, ids)
        new = kf.new_landmark_ids >= 0
        if new.any() and kf.index in self._provisional:
            ids, pos, _ = self._provisional[kf.index]
            self._place.set_landmarks(ids, pos)

    def _remember_update(self, update) -> None:
        if self._place is None or not self._place_live:
            return
        self._place.set_landmarks(update.landmark_ids, update.positions)
        for k, T in update.keyframe_poses.items():
            self._place.set_pose(int(k), T)

    # ------------------------------------------------------------------ relocalisation
    def _relocalise_by_query(self, frame, feats, stereo) -> TrackingResult:
        rel = self._place.relocalise(frame.index, feats.uv, np.where(stereo.valid, stereo.u_right, -1.0),
                                     np.where(stereo.valid, stereo.depth, -1.0), feats.octave, feats.descriptors)
        if rel is None:
            self.n_lost += 1
            if self._initialised:
                self._lost_streak += 1
            return TrackingResult(frame.index, frame.timestamp, self._T_last.copy(), "lost", 0, 0, False, None,
                                  self._ref_kf, lost_reason=LOST_NOT_RELOCALISED)
        T_wc = rel.T_world_cam
        self._initialised = True
        self._awaiting_map = False
        self._need_restart = False
        self._lost_streak = 0
        self._n_failed = 0
        self._velocity = np.eye(4)
        self._velocity_valid = False
        self._seen = []
        self._use_local_map_of(rel.keyframe)
        good = rel.landmark_ids >= 0
        known, pos = self._place.positions_of(rel.landmark_ids[good])
        self._last_matched = (pos, as_words(feats.descriptors[good][known]), rel.landmark_ids[good][known])
        self._after_frame(T_wc, feats, stereo)
        self.n_db_relocalised += 1
        return TrackingResult(frame.index, frame.timestamp, T_wc, "ok", rel.n_inliers, rel.n_inliers, False, None,
                              self._ref_kf, T_ref_cam=se3_inv(self._T_ref) @ T_wc,
                              keyframe_reason=f"relocalised_by_query(kf {rel.keyframe})")

    def _use_local_map_of(self, keyframe: int) -> None:
        """Reference keyframe := ``keyframe`` of the memory; map view := its local map."""
        ids, pos, desc = self._place.local_map([keyframe])
        self._update_view.set(ids, pos, desc)
        self._provisional.clear()
        self._view_dirty = True
        kf = self._place.keyframes[keyframe]
        self._ref_kf = int(keyframe)
        self._T_ref = kf.T_world_cam.copy()
        self._ref_ids = unique_sorted(kf.landmark_ids[kf.landmark_ids >= 0])
        self._frames_since_kf = 0
        self._entropy_first = None
        self._ref_tracked_first = None

    def _switch_reference(self, matched_ids: np.ndarray) -> bool:
        """Localisation mode: instead of a new keyframe, the map keyframe sharing most landmarks
        with this frame becomes the reference and its covisible keyframes the local map."""
        best = self._place.best_keyframe(matched_ids)
        if best is None:
            return False
        self._use_local_map_of(best)
        return True
