"""The tracker's side of the local map (a mixin of ``canopy.frontend.tracker.Tracker``): local
mapping's updates replace the view (``canopy.frontend.map_view.MapView``) and correct the
reference keyframe's pose, and the view tracking searches is the last update plus the provisional
landmarks of keyframes not yet acknowledged. Uses the tracker's ``_update_view``,
``_provisional``, ``_view``, line views and motion state.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.geometry import se3_inv, transform
from canopy.frontend.map_view import MapView, merge_views
from canopy.frontend.messages import LocalMapUpdate


def _refreshed_matches(last_matched, ids, positions):
    """(positions, words, ids) of the last frame's matches re-read from a map update (by id)."""
    pos, words, lids = last_matched
    ids = np.asarray(ids, np.int64)
    if not len(lids) or not len(ids):
        return pos[:0], words[:0], lids[:0]
    order = np.argsort(ids)
    j = np.clip(np.searchsorted(ids[order], lids), 0, len(ids) - 1)
    found = ids[order][j] == lids
    return np.asarray(positions, float)[order][j[found]], words[found], lids[found]


class TrackerMapViewMixin:
    """``apply_map_update`` and the merged view (see the module docstring)."""

    def apply_map_update(self, update: LocalMapUpdate) -> None:
        """Replace the local-map view and apply corrected keyframe poses."""
        if update.keyframe_index < self._segment_start_kf:
            return  # stale update from a map segment before a restart
        self._remember_update(update)  # relocalisation by database query (tracker_reloc)
        self._update_view.set(update.landmark_ids, update.positions, update.descriptors)
        for k in [k for k in self._provisional if k <= update.keyframe_index]:
            del self._provisional[k]
        self._view_dirty = True
        if self._lines_on:
            self._line_update_view.set(update.line_ids, update.line_endpoints, update.line_descriptors)
            for k in [k for k in self._line_provisional if k <= update.keyframe_index]:
                del self._line_provisional[k]
            self._line_view_dirty = True
        if self._ref_kf in update.keyframe_poses:
            T_new = np.asarray(update.keyframe_poses[self._ref_kf], float)
            C = T_new @ se3_inv(self._T_ref)  # world correction of the reference keyframe
            self._T_ref = T_new
            self._T_last = C @ self._T_last
            if self._last_points_w is not None:
                self._last_points_w = transform(C, self._last_points_w)
        epoch = int(getattr(update, "loop_epoch", 0))
        if epoch > self._loop_epoch_seen:
            # a loop correction moved the map: the last frame's matched landmarks take their corrected
            # positions (projected uncorrected with the corrected prediction they missed by the whole
            # correction: 62 matches and a 0.37 m frame on the day-loop); those no longer in the map go
            self._loop_epoch_seen = epoch
            self._last_matched = _refreshed_matches(self._last_matched, update.landmark_ids, update.positions)

    def _map_view(self) -> MapView:
        if self._view_dirty:
            merge_views(self._update_view, self._provisional, self._view)
            self._view_dirty = False
        return self._view
