"""Monocular local mapping (ORB-SLAM LocalMapping, monocular): keyframe insertion, new points
triangulated between covisible keyframes, local bundle adjustment in GTSAM with monocular
projection factors (``GenericProjectionFactorCal3_S2``) under a Huber kernel, culling.

``MonoMapper.insert_keyframe(KeyframeData) -> LocalMapUpdate`` is the whole per-keyframe
step, as ``canopy.backend.LocalMapper`` for stereo, so the actors can use either. A
monocular map has no metric scale: its unit is the median depth of the initial two-view
map, and it drifts (the local BA's gauge is fixed by keyframes held constant, seven degrees
of freedom of which only the six of a pose are pinned by each one).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import as_words, match_in_window
from canopy.backend.map_store import MapStoreAccess, local_map_update
from canopy.frontend.messages import KeyframeData, LocalMapUpdate
from canopy.mono.params import MonoParams
from canopy.mono.triangulation import new_points_between
from shared.arrays import unique_sorted
from shared.types import StereoCalibration

X = gtsam.symbol_shorthand.X
L = gtsam.symbol_shorthand.L
# Landmarks triangulated here get ids far above tracking's (tracking reserves ids only for
# the initial two-view map), so the two allocators never collide.
MAPPER_ID_BASE = 1 << 40


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


@dataclass
class MonoKeyframe:
    index: int
    timestamp: float
    T_world_cam: np.ndarray
    uv: np.ndarray
    octave: np.ndarray
    descriptors: np.ndarray
    landmark: np.ndarray      # (N,) landmark id of keypoint i, -1 for none
    segment: int
    order: int


@dataclass
class MonoLandmark:
    id: int
    position: np.ndarray
    descriptor: np.ndarray
    obs: dict[int, int] = field(default_factory=dict)
    first_order: int = 0
    segment: int = 0
    recent: bool = True       # ORB-SLAM mlpRecentAddedMapPoints: culled strictly while recent
    visible: int = 1
    found: int = 1


class MonoMapper(MapStoreAccess):
    def __init__(self, calib: StereoCalibration, params: MonoParams | None = None, pixel_sigma: float = 1.0):
        self.calib = calib
        self.params = (params or MonoParams()).validate()
        self.pixel_sigma = float(pixel_sigma)
        self.keyframes: dict[int, MonoKeyframe] = {}
        self.landmarks: dict[int, MonoLandmark] = {}
        self._segment = -1
        self._segment_first: dict[int, int] = {}
        self._order = 0
        self._next_id = MAPPER_ID_BASE
        self._K = gtsam.Cal3_S2(calib.fx, calib.fy, 0.0, calib.cx, calib.cy)
        self._Kinv = np.linalg.inv(calib.K)
        self._noise_cache: dict[tuple[int, float], gtsam.noiseModel.Base] = {}
        self.timings: list[dict[str, float]] = []
        self.n_culled = 0
        self.n_triangulated = 0
        self.n_fused = 0
        self._scale_factor = 1.2      # ORB pyramid scale, from the keyframes (KeyframeData.scale_factor)

    # ----------------------------------------------------------------- public API
    def insert_keyframe(self, kf: KeyframeData) -> LocalMapUpdate:
        timings: dict[str, float] = {}
        t_all = time.perf_counter()
        t0 = time.perf_counter()
        self._scale_factor = float(kf.scale_factor)
        rec = self._insert(kf)
        timings["insert"] = _ms(t0)
        t0 = time.perf_counter()
        neighbours = self._neighbours(rec, self.params.covisible_for_triangulation)
        self._fuse_into(rec, self._landmarks_of(neighbours), kf.scale_factor)
        timings["fuse_in"] = _ms(t0)
        t0 = time.perf_counter()
        self._triangulate_new_points(rec, kf.scale_factor)
        timings["triangulate"] = _ms(t0)
        t0 = time.perf_counter()
        mine = self._landmarks_of([rec.index])
        for k in neighbours:
            self._fuse_into(self.keyframes[k], mine, kf.scale_factor)
        timings["fuse_out"] = _ms(t0)
        t0 = time.perf_counter()
        local, fixed = self._local_window(rec)
        if len(local) >= 1 and len(local) + len(fixed) >= 2:
            self._bundle_adjust(local, fixed, kf.scale_factor)
        timings["ba"] = _ms(t0)
        t0 = time.perf_counter()
        self._cull(rec)
        timings["cull"] = _ms(t0)
        update = self._make_update(rec, local, fixed)
        timings["total"] = _ms(t_all)
        update.timings = timings
        self.timings.append(timings)
        return update

    def map_lines(self) -> np.ndarray:
        return np.zeros((0, 2, 3))   # the monocular map has points only

    def fuse_loop(self, query: int, candidate: int) -> int:
        """After a loop correction (ORB-SLAM SearchAndFuse): the points around the matched old
        keyframe are projected into the query keyframe and its neighbours, so the two passes
        over the place share landmarks (and covisibility) from now on. Returns merges + new
        observations made."""
        if query not in self.keyframes or candidate not in self.keyframes:
            return 0
        n = self.params.fuse_loop_neighbours
        old_side = [candidate] + self._neighbours(self.keyframes[candidate], n)
        new_side = [query] + self._neighbours(self.keyframes[query], n)
        lm_old = self._landmarks_of(old_side)
        before = self.n_fused + sum(len(lm.obs) for lm in self.landmarks.values())
        for k in new_side:
            self._fuse_into(self.keyframes[k], lm_old, self._scale_factor)
        return self.n_fused + sum(len(lm.obs) for lm in self.landmarks.values()) - before

    def local_map_around(self, kf_index: int) -> LocalMapUpdate:
        """The local map of keyframe ``kf_index`` (it and its best covisible keyframes), for a
        tracker relocalised against it."""
        local = [kf_index] + self._neighbours(self.keyframes[kf_index], self.params.window_size - 1)
        return local_map_update(kf_index, self.keyframes, self.landmarks, local, [])

    # ----------------------------------------------------------------- insertion
    def _insert(self, kf: KeyframeData) -> MonoKeyframe:
        if kf.restart or self._segment < 0:
            self._segment += 1
            self._segment_first[self._segment] = kf.index
        n = len(kf)
        rec = MonoKeyframe(kf.index, kf.timestamp, np.asarray(kf.T_world_cam, float).copy(),
                           np.asarray(kf.uv, np.float64), np.asarray(kf.octave, np.int64),
                           np.asarray(kf.descriptors, np.uint8), np.full(n, -1, np.int64), self._segment, self._order)
        self._order += 1
        self.keyframes[kf.index] = rec
        self._add_seen_counts(kf)
        for i in np.flatnonzero(kf.landmark_ids >= 0).tolist():
            lm = self.landmarks.get(int(kf.landmark_ids[i]))
            if lm is None or lm.segment != self._segment or kf.index in lm.obs:
                continue
            lm.obs[kf.index] = i
            lm.visible += 1
            lm.found += 1
            lm.descriptor = rec.descriptors[i].copy()   # the newest view matches the next frames best
            rec.landmark[i] = lm.id
        # the initial two-view map: depths triangulated by tracking (median depth 1)
        idx = np.flatnonzero((kf.new_landmark_ids >= 0) & (rec.landmark < 0) & (kf.depth > 0))
        if len(idx):
            z = kf.depth[idx].astype(np.float64)
            rays = np.column_stack([rec.uv[idx], np.ones(len(idx))]) @ self._Kinv.T
            Pw = (rays * z[:, None]) @ rec.T_world_cam[:3, :3].T + rec.T_world_cam[:3, 3]
            for j, i in enumerate(idx.tolist()):
                lid = int(kf.new_landmark_ids[i])
                self.landmarks[lid] = MonoLandmark(lid, Pw[j], rec.descriptors[i].copy(), {kf.index: i},
                                                   first_order=rec.order, segment=self._segment, recent=False)
                rec.landmark[i] = lid
        return rec

    # ----------------------------------------------------------------- covisibility
    def _covisible(self, rec: MonoKeyframe) -> dict[int, int]:
        counts: dict[int, int] = {}
        for lid in rec.landmark[rec.landmark >= 0].tolist():
            for k in self.landmarks[lid].obs:
                if k != rec.index:
                    counts[k] = counts.get(k, 0) + 1
        return counts

    def _neighbours(self, rec: MonoKeyframe, n: int) -> list[int]:
        counts = self._covisible(rec)
        neigh = [k for k in counts if self.keyframes[k].segment == rec.segment]
        neigh.sort(key=lambda k: (-counts[k], -k))
        return neigh[:n]

    # ----------------------------------------------------------------- fusion
    def _landmarks_of(self, kf_indices) -> list[int]:
        ids: set[int] = set()
        for k in kf_indices:
            lm = self.keyframes[k].landmark
            ids.update(lm[lm >= 0].tolist())
        return sorted(ids)

    def _fuse_into(self, target: MonoKeyframe, lm_ids: list[int], scale: float) -> None:
        """ORB-SLAM Fuse (SearchInNeighbors): project landmarks into ``target`` and search a
        small window; a free keypoint gains the observation, a keypoint holding another
        landmark means two landmarks are one point: the one with fewer views is merged into
        the other. Longer tracks carry the map's scale further (less scale drift)."""
        lm_ids = [l for l in lm_ids if l in self.landmarks and target.index not in self.landmarks[l].obs
                  and self.landmarks[l].segment == target.segment]
        if not lm_ids or len(target.uv) == 0:
            return
        p = self.params
        pos = np.array([self.landmarks[l].position for l in lm_ids])
        desc = np.array([self.landmarks[l].descriptor for l in lm_ids], np.uint8)
        T_cw = se3_inv(target.T_world_cam)
        Pc = pos @ T_cw[:3, :3].T + T_cw[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = Pc[:, :2] / Pc[:, 2:3] * [self.calib.fx, self.calib.fy] + [self.calib.cx, self.calib.cy]
        in_view = ((Pc[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < self.calib.width)
                   & (uv[:, 1] >= 0) & (uv[:, 1] < self.calib.height))
        if not in_view.any():
            return
        q, r, _ = match_in_window(np.where(in_view[:, None], uv, 0.0), as_words(desc),
                                  np.full(len(lm_ids), p.fuse_radius), target.uv, as_words(target.descriptors),
                                  p.triangulation_max_hamming, p.fuse_ratio, q_mask=in_view,
                                  r_scale=scale ** target.octave.astype(float))
        for qi, ri in zip(q.tolist(), r.tolist()):
            lid = lm_ids[qi]
            lm = self.landmarks.get(lid)
            if lm is None or target.index in lm.obs:
                continue
            other = int(target.landmark[ri])
            if other < 0:
                lm.obs[target.index] = ri
                target.landmark[ri] = lid
            elif other != lid and other in self.landmarks:
                keep, drop = (lm, self.landmarks[other])
                if len(drop.obs) > len(keep.obs):
                    keep, drop = drop, keep
                self._merge(keep, drop)

    def _merge(self, keep: MonoLandmark, drop: MonoLandmark) -> None:
        for k, i in drop.obs.items():
            if k not in keep.obs:
                keep.obs[k] = i
                self.keyframes[k].landmark[i] = keep.id
            else:
                self.keyframes[k].landmark[i] = -1
        keep.visible += drop.visible
        keep.found += drop.found
        del self.landmarks[drop.id]
        self.n_fused += 1

    # ----------------------------------------------------------------- new points
    def _triangulate_new_points(self, rec: MonoKeyframe, scale: float) -> None:
        """ORB-SLAM CreateNewMapPoints: match the keyframe's unmatched keypoints with those of
        its covisible keyframes along epipolar lines and triangulate the pairs that pass the
        parallax, depth, reprojection and scale-consistency checks."""
        for k in self._neighbours(rec, self.params.covisible_for_triangulation):
            if k in self.keyframes:
                self._triangulate_pair(rec, self.keyframes[k], scale)

    def _triangulate_pair(self, a: MonoKeyframe, b: MonoKeyframe, scale: float) -> None:
        p = self.params
        Tb = se3_inv(b.T_world_cam)
        baseline = np.linalg.norm(a.T_world_cam[:3, 3] - b.T_world_cam[:3, 3])
        lm_b = b.landmark[b.landmark >= 0]
        if len(lm_b) == 0:
            return
        Pb = np.array([self.landmarks[l].position for l in lm_b.tolist()]) @ Tb[:3, :3].T + Tb[:3, 3]
        if baseline / max(float(np.median(Pb[:, 2])), 1e-9) < p.min_baseline_depth_ratio:
            return
        ka, kb, Pw = new_points_between(a, b, self.calib, p, scale, self.pixel_sigma)
        for j in range(len(ka)):
            lid = self._next_id
            self._next_id += 1
            i_a, i_b = int(ka[j]), int(kb[j])
            self.landmarks[lid] = MonoLandmark(lid, Pw[j].copy(), a.descriptors[i_a].copy(),
                                               {a.index: i_a, b.index: i_b}, first_order=a.order, segment=a.segment)
            a.landmark[i_a] = lid
            b.landmark[i_b] = lid
        self.n_triangulated += len(ka)

    # ----------------------------------------------------------------- local BA
    def _local_window(self, rec: MonoKeyframe) -> tuple[list[int], list[int]]:
        """ORB-SLAM LocalBundleAdjustment: the keyframe and its covisible neighbours are
        optimised; the other keyframes seeing their points are held fixed, and so is the map
        segment's first keyframe."""
        local = [rec.index] + self._neighbours(rec, self.params.window_size - 1)
        local_set = set(local)
        fixed_set: set[int] = set()
        for k in local:
            for lid in self.keyframes[k].landmark[self.keyframes[k].landmark >= 0].tolist():
                fixed_set.update(o for o in self.landmarks[lid].obs if o not in local_set)
        first = self._segment_first[rec.segment]
        if first in local_set and len(local) > 1:
            local.remove(first)
            fixed_set.add(first)
        return local, sorted(fixed_set)

    def _noise(self, octave: int, scale: float):
        key = (octave, scale)
        m = self._noise_cache.get(key)
        if m is None:
            base = gtsam.noiseModel.Isotropic.Sigma(2, self.pixel_sigma * scale**octave)
            m = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(self.params.huber), base)
            self._noise_cache[key] = m
        return m

    def _edges(self, local: list[int], kf_set: set[int]):
        lm_ids, e_kf, e_lm, e_kp = self._observation_edges(local, kf_set)
        uv = np.empty((len(e_kf), 2))
        octv = np.empty(len(e_kf), np.int64)
        for k in unique_sorted(e_kf).tolist():
            m = e_kf == k
            uv[m] = self.keyframes[k].uv[e_kp[m]]
            octv[m] = self.keyframes[k].octave[e_kp[m]]
        return lm_ids, e_kf, e_lm, uv, octv

    def _edge_chi2(self, values, e_kf, e_lm, uv, octv, scale) -> np.ndarray:
        T_cw = {k: se3_inv(values.atPose3(X(k)).matrix()) for k in unique_sorted(e_kf).tolist()}
        R = np.stack([T_cw[k][:3, :3] for k in e_kf.tolist()])
        t = np.stack([T_cw[k][:3, 3] for k in e_kf.tolist()])
        uniq, inv = np.unique(e_lm, return_inverse=True)
        P = np.array([values.atPoint3(L(l)) for l in uniq.tolist()], float).reshape(-1, 3)[inv]
        Pc = np.einsum("nij,nj->ni", R, P) + t
        z = Pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.calib.fx * Pc[:, 0] / z + self.calib.cx
            v = self.calib.fy * Pc[:, 1] / z + self.calib.cy
        chi2 = ((uv[:, 0] - u) ** 2 + (uv[:, 1] - v) ** 2) / (self.pixel_sigma * scale**octv) ** 2
        chi2[~(z > 0)] = np.inf
        return chi2

    def _bundle_adjust(self, local: list[int], fixed: list[int], scale: float) -> None:
        p = self.params
        kf_set = set(local) | set(fixed)
        lm_ids, e_kf, e_lm, uv, octv = self._edges(local, kf_set)
        if not lm_ids:
            return
        values = gtsam.Values()
        for k in sorted(kf_set):
            values.insert(X(k), gtsam.Pose3(self.keyframes[k].T_world_cam))
        for lid in lm_ids:
            values.insert(L(lid), self.landmarks[lid].position)
        active = np.ones(len(e_kf), bool)
        fixed_noise = gtsam.noiseModel.Isotropic.Sigma(6, p.fixed_pose_sigma)
        for _ in range(p.ba_passes):
            graph = gtsam.NonlinearFactorGraph()
            for k in fixed:
                graph.add(gtsam.PriorFactorPose3(X(k), gtsam.Pose3(self.keyframes[k].T_world_cam), fixed_noise))
            for j in np.flatnonzero(active).tolist():
                graph.add(gtsam.GenericProjectionFactorCal3_S2(
                    gtsam.Point2(uv[j, 0], uv[j, 1]), self._noise(int(octv[j]), scale),
                    X(int(e_kf[j])), L(int(e_lm[j])), self._K))
            lm_params = gtsam.LevenbergMarquardtParams()
            lm_params.setMaxIterations(p.ba_iterations)
            try:
                values = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params).optimize()
            except RuntimeError:   # an indeterminant system (e.g. a point seen along one ray): keep the estimate
                return
            bad = self._edge_chi2(values, e_kf, e_lm, uv, octv, scale) > p.chi2_mono
            if not (active & bad).any():
                break
            active &= ~bad
        for k in local:
            self.keyframes[k].T_world_cam = values.atPose3(X(k)).matrix()
        for lid in lm_ids:
            self.landmarks[lid].position = np.asarray(values.atPoint3(L(lid)), float)
        bad = ~active | (self._edge_chi2(values, e_kf, e_lm, uv, octv, scale) > p.chi2_mono)
        for j in np.flatnonzero(bad).tolist():
            self._remove_observation(int(e_lm[j]), int(e_kf[j]))

    # ----------------------------------------------------------------- culling
    def _cull(self, rec: MonoKeyframe) -> None:
        """ORB-SLAM MapPointCulling (monocular: a recent point must be seen by more than two
        keyframes once two keyframes have passed), plus points left with < 2 observations."""
        p = self.params
        bad = []
        for lid, lm in self.landmarks.items():
            if len(lm.obs) < 2:
                if lm.first_order < rec.order:   # (the initial map gets its second view next)
                    bad.append(lid)
                continue
            if not lm.recent or lm.segment != rec.segment:
                continue
            age = rec.order - lm.first_order
            if lm.found < p.min_found_ratio * lm.visible:
                bad.append(lid)
            elif age >= p.cull_age_keyframes and len(lm.obs) <= p.min_observations:
                bad.append(lid)
            elif age >= p.cull_age_keyframes + 1:
                lm.recent = False
        for lid in bad:
            self._delete_landmark(lid)

    # ----------------------------------------------------------------- update for tracking
    def _make_update(self, rec: MonoKeyframe, local: list[int], fixed: list[int]) -> LocalMapUpdate:
        return local_map_update(rec.index, self.keyframes, self.landmarks, local, fixed)
