"""Local mapping (AGRI §3.3): keyframe insertion, stereo landmark creation, local bundle
adjustment in GTSAM (Eq. 8-11, point terms; with ``MappingParams.use_lines`` also the line
terms of Eq. 10 on line landmarks with two Point3 endpoints) with Huber kernels, culling.

``LocalMapper`` owns keyframes, landmarks and their observations (covisibility is derived
from shared observations). ``insert_keyframe(KeyframeData) -> LocalMapUpdate`` is the
whole per-keyframe step; nothing here knows about processes.

Where things are:
* the stores: ``LocalMapper.keyframes`` (frame index -> ``Keyframe``), ``LocalMapper.landmarks``
  (id -> ``Landmark``), ``LocalMapper.lines`` (id -> ``LineLandmark``); records in
  ``canopy.backend.map_store``;
* local bundle adjustment: ``canopy.backend.local_ba.LocalBundleAdjustmentMixin``;
* insertion, covisibility window, culling and the update for tracking: here.
"""
from __future__ import annotations

import time
from operator import attrgetter

import gtsam
import numpy as np

from canopy.backend.attitude_prior import AttitudeStore
from canopy.backend.keyframe_culling import cull_redundant_keyframes
from canopy.backend.local_ba import LocalBundleAdjustmentMixin
from canopy.backend.map_store import Keyframe, Landmark, LandmarkStore, LineLandmark, MapStoreAccess, _sorted_unique_ids, \
    local_map_update
from canopy.backend.observations import ObservationTable, observation_reader
from canopy.backend.params import MappingParams
from canopy.backend import point_confirmation as confirmation
from canopy.backend.still_window import bounded_fixed, window_neighbours
from canopy.backend.triangulation import check_tracker_ids, pair_gates, triangulate_with_partners, \
    triangulation_partners
from canopy.frontend.matching import as_words, _popcount64
from canopy.frontend.messages import KeyframeData, LocalMapUpdate
from canopy.lines import line_coefficients
from canopy.lines.geometry import extend_segment
from shared.types import StereoCalibration

__all__ = ["Keyframe", "Landmark", "LineLandmark", "LocalMapper"]


_ID = attrgetter("id")


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


def distinctive_index(desc: np.ndarray) -> np.ndarray:
    """Per group of ``n`` descriptors (G, n, 32): the index of the one with the least median Hamming
    distance to the group's descriptors (ORB-SLAM's ComputeDistinctiveDescriptors; the first on ties,
    as ``np.argmin(np.median(D, axis=2), axis=1)``). The same indices, ~2-4x cheaper on EuRoC's
    ~20-observation landmarks: the distance matrix summed word by word in uint16 (the (G,n,n,4)
    popcounts summed over their short last axis were ~half the cost) and the median ranked by the
    middle element (odd n) or the sum of the two middle ones (even n: twice the median, exact in
    integers) of the sorted rows, with no float medians."""
    G, n = desc.shape[:2]
    w = np.ascontiguousarray(as_words(desc.reshape(-1, 32)).reshape(G, n, 4).transpose(2, 0, 1))  # (4,G,n)
    D = np.zeros((G, n, n), np.uint16)
    for k in range(4):
        D += _popcount64(w[k][:, :, None] ^ w[k][:, None, :])
    # the rows sorted (numpy's SIMD sort of 16-bit integers: 2-5x cheaper than np.partition with the two
    # middle positions of an even n, and no dearer at odd n; the same order statistics)
    S = np.sort(D, axis=2)
    h = n // 2
    key = S[:, :, h] if n % 2 else S[:, :, h - 1].astype(np.int32) + S[:, :, h]
    return np.argmin(key, axis=1)


class LocalMapper(LocalBundleAdjustmentMixin, MapStoreAccess):
    def __init__(self, calib: StereoCalibration, params: MappingParams | None = None):
        self.calib = calib
        self.params = (params or MappingParams()).validate()
        self.keyframes: dict[int, Keyframe] = {}
        self.landmarks: dict[int, Landmark] = LandmarkStore()
        self._segment = -1
        self._segment_first: dict[int, int] = {}
        self._order = 0
        self._K = gtsam.Cal3_S2Stereo(calib.fx, calib.fy, 0.0, calib.cx, calib.cy, calib.baseline)
        self._Kmono = gtsam.Cal3_S2(calib.fx, calib.fy, 0.0, calib.cx, calib.cy)
        self._noise_cache: dict[tuple[bool, int, float], gtsam.noiseModel.Base] = {}
        self.timings: list[dict[str, float]] = []
        self.n_culled = 0
        self.scale_factor = 1.2   # set from each keyframe (insert_keyframe)
        self.lines: dict[int, LineLandmark] = {}
        self.n_lines_culled = 0
        self._next_triangulated_id = self.params.triangulate_id_base
        # keypoints not to triangulate, per keyframe (mapping.triangulate_skip_stereo)
        self._no_triangulation: dict[int, np.ndarray] = {}
        self.n_triangulated = 0
        # keyframes removed by mapping.keyframe_culling: index -> (parent, T_parent_k, timestamp) (canopy.backend.keyframe_culling)
        self.culled_keyframes: dict[int, tuple[int, np.ndarray, float]] = {}
        self.n_keyframes_culled = 0
        # keyframes at either end of a closed loop: never culled (ORB-SLAM's SetNotErase on the loop's
        # two keyframes, LoopClosing::ComputeSim3 / KeyFrame::AddLoopEdge)
        self.loop_keyframes: set[int] = set()
        self._insert_table: ObservationTable | None = None   # _insert's, taken by insert_keyframe
        # measured ups of the keyframes (mapping.attitude_prior; canopy.backend.attitude_prior)
        self.attitude = AttitudeStore(self.params.attitude_reference_keyframes)

    # ----------------------------------------------------------------- public API
    def insert_keyframe(self, kf: KeyframeData) -> LocalMapUpdate:
        timings: dict[str, float] = {}
        t_all = time.perf_counter()
        t0 = time.perf_counter()
        rec = self._insert(kf)
        self.scale_factor = float(kf.scale_factor)   # the pyramid's, for BA's sigmas after the run (final_ba)
        if self.params.attitude_prior:
            self.attitude.add(rec.index, rec.segment, rec.T_world_cam, kf.up_cam, kf.up_sigma_deg)
        # the observations of rec's landmarks as insertion left them (map_store.ObservationTable): read
        # once for the descriptors, covisibility, the window and BA's edges; nothing changes them in between
        table, self._insert_table = self._insert_table, None
        timings["insert"] = _ms(t0)
        if self.params.triangulate_new_points:
            t0 = time.perf_counter()
            self._triangulate_new_points(rec, kf.scale_factor)
            table = None   # new landmarks and fused observations: read afresh
            timings["triangulate"] = _ms(t0)
        t0 = time.perf_counter()
        local, fixed = self._local_window(rec, table)
        self.last_window = (local, fixed)  # for diagnosis (benchmarks/diagnose_drift.py)
        timings["window"] = _ms(t0)
        t0 = time.perf_counter()
        # BA's fixed set bounded by mapping.window_max_fixed (all when 0); tracking's update keeps every
        # keyframe's landmarks (a landmark missing there is made again by tracking from its noisy pose)
        ba_fixed = bounded_fixed(self, rec, local, fixed)
        if len(local) >= 1 and (len(ba_fixed) >= 1 or len(local) >= 2):
            p = self.params
            if p.triangulate_new_points and p.triangulate_confirm and not p.triangulate_confirm_ba:
                # mapping.triangulate_confirm_ba off: the unconfirmed triangulated landmarks sit out BA
                with confirmation.hidden_from_ba(self, confirmation.pending_ids(
                        self.landmarks, p.triangulate_id_base, p.triangulate_min_observations, rec.segment)):
                    self._bundle_adjust(local, ba_fixed, kf.scale_factor, table)
            else:
                self._bundle_adjust(local, ba_fixed, kf.scale_factor, table)
        timings["ba"] = _ms(t0)
        t0 = time.perf_counter()
        self._cull(rec)
        timings["cull"] = _ms(t0)
        if self.params.keyframe_culling:  # ORB-SLAM's KeyFrameCulling, after local BA as there
            t0 = time.perf_counter()
            # BA's outliers and landmark culling changed observations: a new table, kept current by culling
            table = observation_reader(self.landmarks, rec.landmark[rec.landmark >= 0])
            if cull_redundant_keyframes(self, rec, self._covisible(rec, table), table):
                local = [k for k in local if k in self.keyframes]
                fixed = [k for k in fixed if k in self.keyframes]
            timings["kfcull"] = _ms(t0)
        t0 = time.perf_counter()
        update = self._make_update(rec, local, fixed)
        timings["update"] = _ms(t0)
        timings["total"] = _ms(t_all)
        update.timings = timings
        self.timings.append(timings)
        return update

    def keep_loop_edge(self, a: int, b: int) -> None:
        """Keyframes ``a`` and ``b`` carry a loop edge: keyframe culling leaves them in the map."""
        self.loop_keyframes.update((int(a), int(b)))

    def map_lines(self) -> np.ndarray:
        """(L,2,3) endpoints A, B (world) of every line landmark, in id order."""
        if not self.lines:
            return np.zeros((0, 2, 3))
        return np.array([self.lines[i].endpoints for i in sorted(self.lines)], float)

    # ----------------------------------------------------------------- insertion
    def _insert(self, kf: KeyframeData) -> Keyframe:
        if kf.restart or self._segment < 0:
            self._segment += 1
            self._segment_first[self._segment] = kf.index
        n = len(kf)
        if self.params.triangulate_new_points:
            check_tracker_ids(kf.new_landmark_ids, self.params.triangulate_id_base)
            if self.params.triangulate_skip_stereo:
                # a valid stereo depth tracking made no landmark of: on an occluding contour (its
                # depth mixes fore- and background, and across keyframes the keypoint slides along
                # the silhouette: no fixed 3-D point) or beyond tracking.max_depth_baselines
                d = np.asarray(kf.depth, np.float64)
                self._no_triangulation[kf.index] = np.isfinite(d) & (d > 0) & (np.asarray(kf.new_landmark_ids) < 0)
        rec = Keyframe(kf.index, kf.timestamp, np.asarray(kf.T_world_cam, float).copy(),
                       np.asarray(kf.uv, np.float64), np.asarray(kf.u_right, np.float64),
                       np.asarray(kf.octave, np.int64), np.asarray(kf.descriptors, np.uint8),
                       np.full(n, -1, np.int64), self._segment, self._order)
        self._order += 1
        self.keyframes[kf.index] = rec
        self._add_seen_counts(kf)   # ORB-SLAM's found/visible statistics collected by tracking
        # observations of existing landmarks: written to the dicts with dict's own method and to the
        # store's arrays in one append (ObsDict's hook per observation cost ~1 us each)
        touched, t_rows, t_ids = [], [], []
        seen_rows = np.flatnonzero(kf.landmark_ids >= 0)
        get, k_new, seg, setobs = self.landmarks.get, kf.index, self._segment, dict.__setitem__
        for i, lid in zip(seen_rows.tolist(), np.asarray(kf.landmark_ids)[seen_rows].tolist()):
            lm = get(lid)
            if lm is None or lm.segment != seg or k_new in lm._obs:
                continue  # culled meanwhile, or from an older map segment
            setobs(lm._obs, k_new, i)
            lm.visible += 1
            lm.found += 1
            t_rows.append(i)
            t_ids.append(lid)
            touched.append(lm)
        t_rows, t_ids = np.array(t_rows, np.int64), np.array(t_ids, np.int64)
        rec.landmark[t_rows] = t_ids
        st = getattr(self.landmarks, "observations", None)
        if st is not None:
            st.append(t_ids, k_new, t_rows)
        # new landmarks from stereo: X = ((u-cx) z / fx, (v-cy) z / fy, z), then to world
        idx = np.flatnonzero((kf.new_landmark_ids >= 0) & (rec.landmark < 0) & (kf.depth > 0))
        z = kf.depth[idx].astype(np.float64)
        Pc = np.stack([(rec.uv[idx, 0] - self.calib.cx) * z / self.calib.fx,
                       (rec.uv[idx, 1] - self.calib.cy) * z / self.calib.fy, z], axis=1)
        Pw = Pc @ rec.T_world_cam[:3, :3].T + rec.T_world_cam[:3, 3]
        # the new landmarks' positions and descriptors written to the store's rows in one go
        self.landmarks.add_new([Landmark(lid, None, None, {kf.index: i}, first_order=rec.order, segment=self._segment)
                                for i, lid in zip(idx.tolist(), np.asarray(kf.new_landmark_ids)[idx].tolist())],
                               Pw, rec.descriptors[idx])
        rec.landmark[idx] = np.asarray(kf.new_landmark_ids)[idx]
        self._insert_table = observation_reader(self.landmarks, rec.landmark[rec.landmark >= 0])
        self._update_descriptors(touched, self._insert_table)
        if self.params.use_lines:
            self._insert_lines(kf, rec)
        return rec

    def _triangulate_new_points(self, rec: Keyframe, scale: float) -> None:
        """ORB-SLAM CreateNewMapPoints in the stereo map (canopy.backend.triangulation): new
        landmarks from rec's free keypoints matched with its best covisible keyframes', each
        with a monocular observation in both (local BA then weighs them as mono edges, or as
        stereo ones where the keypoint has a right-image match)."""
        p = self.params
        if p.triangulate_fuse:   # Fuse (point_confirmation): the pending landmarks searched in rec
            confirmation.fuse_into(self, rec, confirmation.pending_ids(
                self.landmarks, p.triangulate_id_base, p.triangulate_min_observations, rec.segment), scale)
        counts = self._covisible(rec)
        partners = triangulation_partners(rec, self.keyframes, counts, p.triangulate_covisible,
                                          p.triangulate_min_baseline * self.calib.baseline)
        first_new = self._next_triangulated_id
        for k, ka, kb, Pw in triangulate_with_partners(rec, self.keyframes, partners, self.calib, pair_gates(p),
                                                       scale, p.pixel_sigma, self._no_triangulation):
            b = self.keyframes[k]
            ids = self._next_triangulated_id + np.arange(len(ka), dtype=np.int64)
            self._next_triangulated_id += len(ka)
            self.landmarks.add_new([Landmark(lid, None, None, {rec.index: i, k: j}, first_order=rec.order,
                                             segment=self._segment)
                                    for lid, i, j in zip(ids.tolist(), ka.tolist(), kb.tolist())],
                                   Pw, rec.descriptors[ka])
            rec.landmark[ka] = ids
            b.landmark[kb] = ids
            self.n_triangulated += len(ka)
        if p.triangulate_fuse and self._next_triangulated_id > first_new:
            # and rec's new landmarks searched in its best covisible keyframes (SearchInNeighbors)
            new_ids = np.arange(first_new, self._next_triangulated_id, dtype=np.int64)
            neigh = sorted((k for k in counts if self.keyframes[k].segment == rec.segment),
                           key=lambda k: (-counts[k], -k))[: p.triangulate_fuse_neighbours]
            for k in neigh:
                confirmation.fuse_into(self, self.keyframes[k], new_ids, scale)

    def _insert_lines(self, kf: KeyframeData, rec: Keyframe) -> None:
        """Line observations of existing line landmarks, and new lines from stereo endpoints."""
        n = len(kf.line_ids)
        rec.line_segments = np.asarray(kf.line_segments, np.float64).reshape(-1, 4)
        rec.line_segments_right = np.asarray(kf.line_segments_right, np.float64).reshape(-1, 4)
        rec.line_coeffs = line_coefficients(rec.line_segments)
        with np.errstate(invalid="ignore"):
            rec.line_coeffs_right = line_coefficients(np.asarray(kf.line_segments_right, np.float64).reshape(-1, 4))
        rec.line_descriptors = np.asarray(kf.line_descriptors, np.uint8).reshape(-1, 32)
        rec.line_landmark = np.full(n, -1, np.int64)
        for j in np.flatnonzero(kf.line_ids >= 0).tolist():
            ln = self.lines.get(int(kf.line_ids[j]))
            if ln is None or ln.segment != self._segment or kf.index in ln.obs:
                continue
            ln.obs[kf.index] = j
            ln.descriptor = rec.line_descriptors[j].copy()
            rec.line_landmark[j] = ln.id
            # a longer view of the line extends the landmark (BA then refines the endpoints)
            ln.endpoints = np.stack(extend_segment(ln.endpoints[0], ln.endpoints[1], kf.line_segments[j],
                                                   rec.T_world_cam, self.calib, self.params.line_max_growth))
        P = np.asarray(kf.line_endpoints_cam, np.float64).reshape(-1, 2, 3)
        idx = np.flatnonzero((kf.new_line_ids >= 0) & (rec.line_landmark < 0) & np.isfinite(P).all(axis=(1, 2)))
        Pw = (P[idx].reshape(-1, 3) @ rec.T_world_cam[:3, :3].T + rec.T_world_cam[:3, 3]).reshape(-1, 2, 3)
        for j, i in enumerate(idx.tolist()):
            lid = int(kf.new_line_ids[i])
            self.lines[lid] = LineLandmark(lid, Pw[j], rec.line_descriptors[i].copy(), {kf.index: i},
                                           first_order=rec.order, segment=self._segment)
            rec.line_landmark[i] = lid

    def _update_descriptors(self, landmarks: list[Landmark], table: ObservationTable | None = None) -> None:
        """ORB-SLAM's distinctive descriptor: the observation with the least median distance to
        the others. Batched over landmarks with the same number of observations. ``table``: a
        current snapshot of (at least) these landmarks' observations when the store keeps none."""
        ids = np.fromiter(map(_ID, landmarks), np.int64, len(landmarks))
        e_kf, e_kp, n_all = observation_reader(self.landmarks, ids, table).of(ids)
        first = np.cumsum(n_all) - n_all
        sel = np.flatnonzero(n_all >= 3)
        if len(sel) == 0:
            return
        n_all, first = n_all[sel], first[sel]
        m = self.params.descriptor_max_observations   # 0: every observation (ORB-SLAM's)
        n_used = np.minimum(n_all, m) if m else n_all
        # each landmark's last n_used observations (still_window.descriptor_observations: the newest m)
        first = first + n_all - n_used
        # every observation's descriptor by one gather from the observing keyframes' descriptor
        # arrays laid end to end, the keyframes' offsets by a lookup table (np.array over nested
        # lists of 32-byte rows cost ~2 ms per KITTI keyframe)
        kf_ids = _sorted_unique_ids(e_kf).tolist()
        desc_table = np.concatenate([self.keyframes[k].descriptors for k in kf_ids])
        start = np.cumsum([0] + [len(self.keyframes[k].descriptors) for k in kf_ids[:-1]])
        row_of_kf = np.zeros(kf_ids[-1] + 1, np.int64)
        row_of_kf[kf_ids] = start
        store_rows = self.landmarks.rows
        # landmarks grouped by their number of observations (a group's result does not depend on
        # which landmarks share it: the index is computed per landmark)
        for n in np.unique(n_used).tolist():
            g = np.flatnonzero(n_used == n)
            r = first[g][:, None] + np.arange(n)
            desc = np.take(desc_table, row_of_kf[e_kf[r]] + e_kp[r], axis=0)   # ~8x cheaper than desc_table[...]
            best = distinctive_index(desc)
            chosen = desc[np.arange(len(g)), best]
            lids = ids[sel[g]]
            if store_rows is not None:   # one scatter into the store's descriptor rows
                store_rows.desc[lids] = chosen
            else:
                for lid, d in zip(lids.tolist(), chosen):
                    self.landmarks[lid].descriptor = d.copy()

    # ----------------------------------------------------------------- covisibility window
    def _covisible(self, rec: Keyframe, table: ObservationTable | None = None) -> dict[int, int]:
        """Keyframe index -> landmarks it shares with ``rec`` (every reader orders the keyframes by
        (count, index), so the dict's order is free: ascending here). ``table``: current observations
        of (at least) rec's landmarks (read here when None)."""
        # the observing keyframes of all of rec's landmarks in one array, counted by np.bincount (a
        # Counter over the chained dicts cost ~0.9 ms per EuRoC keyframe with ~20 observers per landmark)
        ids = rec.landmark[rec.landmark >= 0]
        keys = observation_reader(self.landmarks, ids, table).of(ids)[0]
        per_kf = np.bincount(keys) if len(keys) else np.zeros(0, np.int64)
        seen = np.flatnonzero(per_kf)
        counts = dict(zip(seen.tolist(), per_kf[seen].tolist()))
        counts.pop(rec.index, None)
        if self.params.use_lines:  # shared line landmarks make keyframes covisible too
            for lid in rec.line_landmark[rec.line_landmark >= 0].tolist():
                for k in self.lines[lid].obs:
                    if k != rec.index:
                        counts[k] = counts.get(k, 0) + 1
        return counts

    def _local_window(self, rec: Keyframe, table: ObservationTable | None = None) -> tuple[list[int], list[int]]:
        """Current keyframe + its strongest covisible neighbours (local, optimised) and the
        other keyframes seeing their landmarks (fixed), as ORB-SLAM's LocalBundleAdjustment.
        ``table``: current observations of rec's landmarks; the window's others are added to it."""
        p = self.params
        table = observation_reader(self.landmarks, (), table)
        counts = self._covisible(rec, table)
        neigh = [k for k, c in counts.items() if c >= p.covisibility_min_shared
                 and self.keyframes[k].segment == rec.segment]
        neigh.sort(key=lambda k: (-counts[k], -k))
        local = [rec.index] + window_neighbours(self, rec, neigh)  # neigh[:window_size - 1] unless still_window's option
        local_set = set(local)
        # the local keyframes' landmarks by one presence table, their observers from the table and made
        # distinct there (sets built element by element cost ~1 ms per KITTI keyframe)
        seen = _sorted_unique_ids(np.concatenate([self.keyframes[k].landmark for k in local]))
        table.add(seen)
        observers = table.of(seen)[0]
        fixed_set = set(_sorted_unique_ids(observers).tolist()) - local_set
        first = self._segment_first[rec.segment]
        if first in local_set and len(local) > 1:  # the segment's first keyframe fixes the gauge
            local.remove(first)
            fixed_set.add(first)
        return local, sorted(fixed_set)

    # ----------------------------------------------------------------- culling
    def _cull(self, rec: Keyframe) -> None:
        """ORB-SLAM MapPointCulling for recent landmarks, plus landmarks left unobserved."""
        p = self.params
        bad = []
        # the rule's numbers as locals and each landmark's dict by its slot (Landmark.obs is a property,
        # ~0.12 us more a read): the loop visits every landmark (~6 k per KITTI keyframe)
        order, segment, recent, ratio = rec.order, rec.segment, p.recent_age_keyframes, p.min_found_ratio
        cull_age, min_obs = p.cull_age_keyframes, p.min_observations
        tri_base = p.triangulate_id_base if p.triangulate_new_points else None
        for lid, lm in self.landmarks.items():
            obs = lm._obs
            if not obs:
                bad.append(lid)
                continue
            age = order - lm.first_order
            if lm.segment != segment or age > recent:
                continue
            if lm.found < ratio * lm.visible:
                bad.append(lid)
            elif age >= cull_age and len(obs) < min_obs:
                bad.append(lid)
            elif tri_base is not None and lid >= tri_base and age >= cull_age \
                    and len(obs) < p.triangulate_min_observations:
                bad.append(lid)   # a triangulated landmark starts with two observations
        for lid in bad:
            self._delete_landmark(lid)
        if p.use_lines:
            self._cull_lines(rec)

    def _cull_lines(self, rec: Keyframe) -> None:
        """Lines left unobserved, or recent lines not re-observed by line_min_observations keyframes."""
        p = self.params
        bad = []
        for lid, ln in self.lines.items():
            if not ln.obs:
                bad.append(lid)
                continue
            age = rec.order - ln.first_order
            if ln.segment != rec.segment or age > p.recent_age_keyframes:
                continue
            if age >= p.cull_age_keyframes and len(ln.obs) < p.line_min_observations:
                bad.append(lid)
        for lid in bad:
            ln = self.lines.pop(lid)
            for k, j in ln.obs.items():
                self.keyframes[k].line_landmark[j] = -1
            self.n_lines_culled += 1

    # ----------------------------------------------------------------- update for tracking
    def _make_update(self, rec: Keyframe, local: list[int], fixed: list[int]) -> LocalMapUpdate:
        update = local_map_update(rec.index, self.keyframes, self.landmarks, local, fixed)
        p = self.params
        if p.triangulate_new_points and p.triangulate_confirm:   # unconfirmed: not for tracking yet
            confirmation.withhold_unconfirmed(update, self.landmarks, p.triangulate_id_base,
                                              p.triangulate_min_observations)
        if self.params.use_lines:
            lids = sorted({lid for k in list(local) + list(fixed)
                           for lid in self.keyframes[k].line_landmark.tolist() if lid >= 0})
            update.line_ids = np.asarray(lids, np.int64)
            update.line_endpoints = np.array([self.lines[i].endpoints for i in lids], float).reshape(-1, 2, 3)
            update.line_descriptors = np.array([self.lines[i].descriptor for i in lids], np.uint8).reshape(-1, 32)
        return update
