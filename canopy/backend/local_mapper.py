"""Local mapping (AGRI §3.3): keyframe insertion, stereo landmark creation, local bundle
adjustment in GTSAM (Eq. 8-11, point terms; with ``MappingParams.use_lines`` also the line
terms of Eq. 10 on line landmarks with two Point3 endpoints) with Huber kernels, culling.

``LocalMapper`` owns keyframes, landmarks and their observations (covisibility is derived
from shared observations). ``insert_keyframe(KeyframeData) -> LocalMapUpdate`` is the
whole per-keyframe step; nothing here knows about processes.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from canopy.backend.line_factors import (line_custom_factor, line_projection_factors,
                                         line_projection_measurements, right_shift)
from canopy.backend.params import MappingParams
from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import as_words, _popcount64
from canopy.frontend.messages import KeyframeData, LocalMapUpdate
from canopy.lines import line_coefficients
from canopy.lines.geometry import extend_segment
from shared.types import StereoCalibration, Trajectory

X = gtsam.symbol_shorthand.X
L = gtsam.symbol_shorthand.L
EA = gtsam.symbol_shorthand.A  # line landmark start point
EB = gtsam.symbol_shorthand.B  # line landmark end point


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


@dataclass
class Keyframe:
    index: int
    timestamp: float
    T_world_cam: np.ndarray
    uv: np.ndarray
    u_right: np.ndarray
    octave: np.ndarray
    descriptors: np.ndarray
    landmark: np.ndarray      # (N,) landmark id observed by keypoint i, -1 for none
    segment: int
    order: int                # insertion counter (ages of landmarks are counted in keyframes)
    # line observations (empty without lines): infinite lines of the left / right segments
    line_coeffs: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    line_coeffs_right: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # NaN: no stereo
    line_descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    line_landmark: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass
class Landmark:
    id: int
    position: np.ndarray
    descriptor: np.ndarray
    obs: dict[int, int] = field(default_factory=dict)  # keyframe index -> keypoint index
    first_order: int = 0
    segment: int = 0
    visible: int = 1
    found: int = 1


@dataclass
class LineLandmark:
    id: int
    endpoints: np.ndarray                              # (2,3) A, B in world
    descriptor: np.ndarray                             # (32,) LBD of the latest observation
    obs: dict[int, int] = field(default_factory=dict)  # keyframe index -> line row
    first_order: int = 0
    segment: int = 0


class LocalMapper:
    def __init__(self, calib: StereoCalibration, params: MappingParams | None = None):
        self.calib = calib
        self.params = (params or MappingParams()).validate()
        self.keyframes: dict[int, Keyframe] = {}
        self.landmarks: dict[int, Landmark] = {}
        self._segment = -1
        self._segment_first: dict[int, int] = {}
        self._order = 0
        self._K = gtsam.Cal3_S2Stereo(calib.fx, calib.fy, 0.0, calib.cx, calib.cy, calib.baseline)
        self._Kmono = gtsam.Cal3_S2(calib.fx, calib.fy, 0.0, calib.cx, calib.cy)
        self._noise_cache: dict[tuple[bool, int, float], gtsam.noiseModel.Base] = {}
        self.timings: list[dict[str, float]] = []
        self.n_culled = 0
        self.lines: dict[int, LineLandmark] = {}
        self.n_lines_culled = 0

    # ----------------------------------------------------------------- public API
    def insert_keyframe(self, kf: KeyframeData) -> LocalMapUpdate:
        timings: dict[str, float] = {}
        t_all = time.perf_counter()
        t0 = time.perf_counter()
        rec = self._insert(kf)
        timings["insert"] = _ms(t0)
        t0 = time.perf_counter()
        local, fixed = self._local_window(rec)
        timings["window"] = _ms(t0)
        t0 = time.perf_counter()
        if len(local) >= 1 and (len(fixed) >= 1 or len(local) >= 2):
            self._bundle_adjust(local, fixed, kf.scale_factor)
        timings["ba"] = _ms(t0)
        t0 = time.perf_counter()
        self._cull(rec)
        timings["cull"] = _ms(t0)
        t0 = time.perf_counter()
        update = self._make_update(rec, local, fixed)
        timings["update"] = _ms(t0)
        timings["total"] = _ms(t_all)
        update.timings = timings
        self.timings.append(timings)
        return update

    def keyframe_trajectory(self) -> Trajectory:
        idx = sorted(self.keyframes)
        stamps = [self.keyframes[i].timestamp for i in idx]
        poses = [self.keyframes[i].T_world_cam for i in idx] if idx else np.zeros((0, 4, 4))
        return Trajectory(np.asarray(stamps, float), np.asarray(poses, float), meta={"indices": idx})

    def keyframe_poses(self) -> dict[int, np.ndarray]:
        return {i: k.T_world_cam.copy() for i, k in self.keyframes.items()}

    def map_points(self) -> np.ndarray:
        if not self.landmarks:
            return np.zeros((0, 3))
        return np.array([lm.position for lm in self.landmarks.values()], float)

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
        rec = Keyframe(kf.index, kf.timestamp, np.asarray(kf.T_world_cam, float).copy(),
                       np.asarray(kf.uv, np.float64), np.asarray(kf.u_right, np.float64),
                       np.asarray(kf.octave, np.int64), np.asarray(kf.descriptors, np.uint8),
                       np.full(n, -1, np.int64), self._segment, self._order)
        self._order += 1
        self.keyframes[kf.index] = rec
        # ORB-SLAM's found/visible statistics collected by tracking since the last keyframe
        for lid, vis, fnd in zip(kf.seen_ids.tolist(), kf.seen_visible.tolist(), kf.seen_found.tolist()):
            lm = self.landmarks.get(lid)
            if lm is not None:
                lm.visible += vis
                lm.found += fnd
        # observations of existing landmarks
        touched = []
        for i in np.flatnonzero(kf.landmark_ids >= 0).tolist():
            lid = int(kf.landmark_ids[i])
            lm = self.landmarks.get(lid)
            if lm is None or lm.segment != self._segment or kf.index in lm.obs:
                continue  # culled meanwhile, or from an older map segment
            lm.obs[kf.index] = i
            lm.visible += 1
            lm.found += 1
            rec.landmark[i] = lid
            touched.append(lm)
        # new landmarks from stereo: X = ((u-cx) z / fx, (v-cy) z / fy, z), then to world
        idx = np.flatnonzero((kf.new_landmark_ids >= 0) & (rec.landmark < 0) & (kf.depth > 0))
        z = kf.depth[idx].astype(np.float64)
        Pc = np.stack([(rec.uv[idx, 0] - self.calib.cx) * z / self.calib.fx,
                       (rec.uv[idx, 1] - self.calib.cy) * z / self.calib.fy, z], axis=1)
        Pw = Pc @ rec.T_world_cam[:3, :3].T + rec.T_world_cam[:3, 3]
        for j, i in enumerate(idx.tolist()):
            lid = int(kf.new_landmark_ids[i])
            self.landmarks[lid] = Landmark(lid, Pw[j], rec.descriptors[i].copy(), {kf.index: i},
                                           first_order=rec.order, segment=self._segment)
            rec.landmark[i] = lid
        for lm in touched:
            self._update_descriptor(lm)
        if self.params.use_lines:
            self._insert_lines(kf, rec)
        return rec

    def _insert_lines(self, kf: KeyframeData, rec: Keyframe) -> None:
        """Line observations of existing line landmarks, and new lines from stereo endpoints."""
        n = len(kf.line_ids)
        rec.line_coeffs = line_coefficients(np.asarray(kf.line_segments, np.float64).reshape(-1, 4))
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

    def _update_descriptor(self, lm: Landmark) -> None:
        """ORB-SLAM's distinctive descriptor: the observation with the least median distance."""
        if len(lm.obs) < 3:
            return
        desc = np.stack([self.keyframes[k].descriptors[i] for k, i in lm.obs.items()])
        w = as_words(desc)
        D = _popcount64(w[:, None, :] ^ w[None, :, :]).sum(-1)
        lm.descriptor = desc[int(np.argmin(np.median(D, axis=1)))].copy()

    # ----------------------------------------------------------------- covisibility window
    def _covisible(self, rec: Keyframe) -> dict[int, int]:
        counts: dict[int, int] = {}
        for lid in rec.landmark[rec.landmark >= 0].tolist():
            for k in self.landmarks[lid].obs:
                if k != rec.index:
                    counts[k] = counts.get(k, 0) + 1
        if self.params.use_lines:  # shared line landmarks make keyframes covisible too
            for lid in rec.line_landmark[rec.line_landmark >= 0].tolist():
                for k in self.lines[lid].obs:
                    if k != rec.index:
                        counts[k] = counts.get(k, 0) + 1
        return counts

    def _local_window(self, rec: Keyframe) -> tuple[list[int], list[int]]:
        """Current keyframe + its strongest covisible neighbours (local, optimised) and the
        other keyframes seeing their landmarks (fixed), as ORB-SLAM's LocalBundleAdjustment."""
        p = self.params
        counts = self._covisible(rec)
        neigh = [k for k, c in counts.items() if c >= p.covisibility_min_shared
                 and self.keyframes[k].segment == rec.segment]
        neigh.sort(key=lambda k: (-counts[k], -k))
        local = [rec.index] + neigh[: p.window_size - 1]
        local_set = set(local)
        fixed_set: set[int] = set()
        for k in local:
            for lid in self.keyframes[k].landmark[self.keyframes[k].landmark >= 0].tolist():
                fixed_set.update(o for o in self.landmarks[lid].obs if o not in local_set)
        first = self._segment_first[rec.segment]
        if first in local_set and len(local) > 1:  # the segment's first keyframe fixes the gauge
            local.remove(first)
            fixed_set.add(first)
        return local, sorted(fixed_set)

    # ----------------------------------------------------------------- bundle adjustment
    def _noise(self, stereo: bool, octave: int, scale: float):
        key = (stereo, octave, scale)
        m = self._noise_cache.get(key)
        if m is None:
            sigma = self.params.pixel_sigma * scale**octave
            base = gtsam.noiseModel.Isotropic.Sigma(3 if stereo else 2, sigma)
            k = self.params.huber_stereo if stereo else self.params.huber_mono
            m = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k), base)
            self._noise_cache[key] = m
        return m

    def _bundle_adjust(self, local: list[int], fixed: list[int], scale: float) -> None:
        """Minimise AGRI Eq. 11 (point terms, Eq. 9) over the local keyframes and their landmarks."""
        p = self.params
        kf_set = set(local) | set(fixed)
        lm_ids = sorted({lid for k in local for lid in self.keyframes[k].landmark[self.keyframes[k].landmark >= 0].tolist()})
        lines = self._line_edges(local, kf_set) if p.use_lines else None
        if not lm_ids and (lines is None or len(lines[0]) == 0):
            return
        # edges: (kf, landmark, keypoint)
        e_kf, e_lm, e_kp = [], [], []
        for lid in lm_ids:
            for k, i in self.landmarks[lid].obs.items():
                if k in kf_set:
                    e_kf.append(k)
                    e_lm.append(lid)
                    e_kp.append(i)
        e_kf = np.asarray(e_kf)
        e_lm = np.asarray(e_lm)
        e_kp = np.asarray(e_kp)
        uv = np.empty((len(e_kf), 2))
        ur = np.empty(len(e_kf))
        octv = np.empty(len(e_kf), np.int64)
        for k in np.unique(e_kf).tolist():
            m = e_kf == k
            kf = self.keyframes[k]
            uv[m] = kf.uv[e_kp[m]]
            ur[m] = kf.u_right[e_kp[m]]
            octv[m] = kf.octave[e_kp[m]]
        stereo = ur >= 0
        active = np.ones(len(e_kf), bool)
        values = gtsam.Values()
        for k in sorted(kf_set):
            values.insert(X(k), gtsam.Pose3(self.keyframes[k].T_world_cam))
        for lid in lm_ids:
            values.insert(L(lid), self.landmarks[lid].position)
        if lines is not None:
            l_kf, l_id, l_coef, l_right = lines
            for lid in np.unique(l_id).tolist():
                values.insert(EA(lid), self.lines[lid].endpoints[0])
                values.insert(EB(lid), self.lines[lid].endpoints[1])
            # edges far off at the initial estimate stay out of the graph (their residual would
            # dominate the first LM steps) and are judged again after BA; l_out: outliers found
            # by a pass; l_active: usable edges of lines they still constrain
            l_gated = self._line_edge_chi2(values, l_kf, l_id, l_coef, l_right) > p.line_chi2_gate
            l_out = np.zeros(len(l_kf), bool)
        fixed_noise = gtsam.noiseModel.Isotropic.Sigma(6, p.fixed_pose_sigma)
        for _ in range(p.ba_passes):
            graph = gtsam.NonlinearFactorGraph()
            for k in fixed:
                graph.add(gtsam.PriorFactorPose3(X(k), gtsam.Pose3(self.keyframes[k].T_world_cam), fixed_noise))
            for j in np.flatnonzero(active).tolist():
                if stereo[j]:
                    graph.add(gtsam.GenericStereoFactor3D(
                        gtsam.StereoPoint2(uv[j, 0], ur[j], uv[j, 1]), self._noise(True, int(octv[j]), scale),
                        X(int(e_kf[j])), L(int(e_lm[j])), self._K))
                else:
                    graph.add(gtsam.GenericProjectionFactorCal3_S2(
                        gtsam.Point2(uv[j, 0], uv[j, 1]), self._noise(False, int(octv[j]), scale),
                        X(int(e_kf[j])), L(int(e_lm[j])), self._Kmono))
            if lines is not None:
                l_active = self._line_edges_constrained(l_kf, l_id, l_right, ~(l_out | l_gated))
                self._add_line_factors(graph, values, l_kf[l_active], l_id[l_active], l_coef[l_active],
                                       l_right[l_active])
            lm_params = gtsam.LevenbergMarquardtParams()
            lm_params.setMaxIterations(p.ba_iterations)
            if lines is not None:
                lm_params.setRelativeErrorTol(p.line_ba_relative_error_tol)
            values = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params).optimize()
            chi2 = self._edge_chi2(values, e_kf, e_lm, uv, ur, stereo, octv, scale)
            bad = chi2 > np.where(stereo, p.chi2_stereo, p.chi2_mono)
            l_bad_new = False
            if lines is not None:
                l_bad = l_active & (self._line_edge_chi2(values, l_kf, l_id, l_coef, l_right) > p.chi2_line)
                l_bad_new = p.line_outliers_repeat_pass and bool(l_bad.any())
                l_out |= l_bad
            if not (active & bad).any() and not l_bad_new:
                break
            active &= ~bad
        # write back poses and points, drop outlier observations (ORB-SLAM removes them)
        for k in local:
            self.keyframes[k].T_world_cam = values.atPose3(X(k)).matrix()
        for lid in lm_ids:
            self.landmarks[lid].position = np.asarray(values.atPoint3(L(lid)), float)
        if lm_ids:
            chi2 = self._edge_chi2(values, e_kf, e_lm, uv, ur, stereo, octv, scale)
            bad = ~active | (chi2 > np.where(stereo, p.chi2_stereo, p.chi2_mono))
            for j in np.flatnonzero(bad).tolist():
                self._remove_observation(int(e_lm[j]), int(e_kf[j]))
        if lines is not None and len(l_kf):
            for lid in np.unique(l_id).tolist():
                self.lines[lid].endpoints = np.stack([np.asarray(values.atPoint3(EA(lid)), float),
                                                      np.asarray(values.atPoint3(EB(lid)), float)])
            judged = l_active | l_gated
            l_bad = l_out | (judged & (self._line_edge_chi2(values, l_kf, l_id, l_coef, l_right) > p.chi2_line))
            for j in np.flatnonzero(l_bad).tolist():
                self._remove_line_observation(int(l_id[j]), int(l_kf[j]), bool(l_right[j]))

    # ----------------------------------------------------------------- line terms (Eq. 10)
    def _line_edges(self, local: list[int], kf_set: set[int]):
        """Line edges of the lines seen by the local keyframes: (keyframe, line id, line
        coefficients, right image?) for every observation in ``kf_set``. A line enters BA when
        ``line_ba_min_keyframes`` keyframes of the window observe it (a line seen by one keyframe
        only constrains no pose, it only adds two free endpoints) and one of them in the right
        image too: left views alone leave the endpoints' depth free when the camera stands still
        or moves in the line's plane, an indeterminate system that LM only damps, slowly."""
        ids = sorted({lid for k in local for lid in self.keyframes[k].line_landmark.tolist() if lid >= 0})
        e_kf, e_id, e_coef, e_right = [], [], [], []
        for lid in ids:
            for k, j in self.lines[lid].obs.items():
                if k not in kf_set:
                    continue
                kf = self.keyframes[k]
                e_kf.append(k)
                e_id.append(lid)
                e_coef.append(kf.line_coeffs[j])
                e_right.append(False)
                if np.isfinite(kf.line_coeffs_right[j]).all():
                    e_kf.append(k)
                    e_id.append(lid)
                    e_coef.append(kf.line_coeffs_right[j])
                    e_right.append(True)
        edges = (np.asarray(e_kf, np.int64), np.asarray(e_id, np.int64), np.asarray(e_coef, float).reshape(-1, 3),
                 np.asarray(e_right, bool))
        keep = self._line_edges_constrained(edges[0], edges[1], edges[3], np.ones(len(edges[0]), bool))
        return tuple(a[keep] for a in edges)

    def _line_edges_constrained(self, l_kf, l_id, l_right, usable) -> np.ndarray:
        """Mask of the ``usable`` edges whose line is constrained by its usable edges: seen by
        ``line_ba_min_keyframes`` keyframes, once in a right image (see ``_line_edges``)."""
        if len(l_kf) == 0:
            return np.zeros(0, bool)
        uniq, inv = np.unique(l_id, return_inverse=True)
        n_right = np.bincount(inv, weights=(usable & l_right), minlength=len(uniq))
        # distinct keyframes per line among the usable edges
        pairs = np.unique(np.column_stack([inv, l_kf])[usable], axis=0)
        n_kf = np.bincount(pairs[:, 0], minlength=len(uniq)) if len(pairs) else np.zeros(len(uniq), np.int64)
        ok = (n_kf >= self.params.line_ba_min_keyframes) & (n_right >= 1)
        return usable & ok[inv]

    def _add_line_factors(self, graph, values, l_kf, l_id, l_coef, l_right) -> None:
        p = self.params
        if len(l_kf) == 0:
            return
        if p.line_factor == "custom":
            noise = self._line_noise()
            for k, lid, c, r in zip(l_kf.tolist(), l_id.tolist(), l_coef, l_right.tolist()):
                graph.add(line_custom_factor(X(k), EA(lid), EB(lid), c, self.calib, noise, right=r))
            return
        T_wc = {k: values.atPose3(X(k)).matrix() for k in np.unique(l_kf).tolist()}
        T = np.stack([T_wc[k] for k in l_kf.tolist()])
        for which, key in ((0, EA), (1, EB)):
            P = np.array([values.atPoint3(key(lid)) for lid in l_id.tolist()], float).reshape(-1, 3)
            feet, infos = line_projection_measurements(T, P, l_coef, self.calib, l_right, p.line_sigma,
                                                       p.line_sigma_along)
            for f in line_projection_factors([X(k) for k in l_kf.tolist()], [key(lid) for lid in l_id.tolist()],
                                             feet, infos, l_right, self._Kmono, self.calib, p.huber_line):
                graph.add(f)

    def _line_noise(self):
        m = self._noise_cache.get(("line",))
        if m is None:
            base = gtsam.noiseModel.Isotropic.Sigma(2, self.params.line_sigma)
            m = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(self.params.huber_line), base)
            self._noise_cache[("line",)] = m
        return m

    def _line_edge_chi2(self, values, l_kf, l_id, l_coef, l_right) -> np.ndarray:
        """Eq. 11 line term of every edge: (d_A^2 + d_B^2) / line_sigma^2 (inf if behind)."""
        if len(l_kf) == 0:
            return np.zeros(0)
        T_cw = {k: se3_inv(values.atPose3(X(k)).matrix()) for k in np.unique(l_kf).tolist()}
        R = np.stack([T_cw[k][:3, :3] for k in l_kf.tolist()])
        t = np.stack([T_cw[k][:3, 3] for k in l_kf.tolist()])
        t = t + np.where(l_right[:, None], right_shift(self.calib)[:3, 3], 0.0)
        uniq, inv = np.unique(l_id, return_inverse=True)
        chi2 = np.zeros(len(l_kf))
        front = np.ones(len(l_kf), bool)
        for key in (EA, EB):
            P = np.array([values.atPoint3(key(l)) for l in uniq.tolist()], float).reshape(-1, 3)[inv]
            Pc = np.einsum("nij,nj->ni", R, P) + t
            z = Pc[:, 2]
            front &= z > self.params.min_depth
            with np.errstate(divide="ignore", invalid="ignore"):
                u = self.calib.fx * Pc[:, 0] / z + self.calib.cx
                v = self.calib.fy * Pc[:, 1] / z + self.calib.cy
            chi2 += (l_coef[:, 0] * u + l_coef[:, 1] * v + l_coef[:, 2]) ** 2
        chi2 /= self.params.line_sigma**2
        chi2[~front | ~np.isfinite(chi2)] = np.inf
        return chi2

    def _remove_line_observation(self, lid: int, k: int, right: bool) -> None:
        ln = self.lines.get(lid)
        if ln is None or k not in ln.obs:
            return
        if right:  # only the right-image half of the observation is bad
            self.keyframes[k].line_coeffs_right[ln.obs[k]] = np.nan
            return
        j = ln.obs.pop(k)
        self.keyframes[k].line_landmark[j] = -1

    def _edge_chi2(self, values, e_kf, e_lm, uv, ur, stereo, octv, scale) -> np.ndarray:
        """Whitened squared reprojection error of every edge (inf if behind the camera)."""
        T_cw = {k: se3_inv(values.atPose3(X(k)).matrix()) for k in np.unique(e_kf).tolist()}
        R = np.stack([T_cw[k][:3, :3] for k in e_kf.tolist()])
        t = np.stack([T_cw[k][:3, 3] for k in e_kf.tolist()])
        uniq, inv = np.unique(e_lm, return_inverse=True)
        P = np.array([values.atPoint3(L(l)) for l in uniq.tolist()], float).reshape(-1, 3)[inv]
        Pc = np.einsum("nij,nj->ni", R, P) + t
        z = Pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.calib.fx * Pc[:, 0] / z + self.calib.cx
            v = self.calib.fy * Pc[:, 1] / z + self.calib.cy
            urp = u - self.calib.bf / z
        err = (uv[:, 0] - u) ** 2 + (uv[:, 1] - v) ** 2 + np.where(stereo, (ur - urp) ** 2, 0.0)
        chi2 = err / (self.params.pixel_sigma * scale ** octv) ** 2
        chi2[~(z > self.params.min_depth)] = np.inf
        return chi2

    def _remove_observation(self, lid: int, k: int) -> None:
        lm = self.landmarks.get(lid)
        if lm is None or k not in lm.obs:
            return
        i = lm.obs.pop(k)
        self.keyframes[k].landmark[i] = -1

    def _delete_landmark(self, lid: int) -> None:
        lm = self.landmarks.pop(lid)
        for k, i in lm.obs.items():
            self.keyframes[k].landmark[i] = -1
        self.n_culled += 1

    # ----------------------------------------------------------------- culling
    def _cull(self, rec: Keyframe) -> None:
        """ORB-SLAM MapPointCulling for recent landmarks, plus landmarks left unobserved."""
        p = self.params
        bad = []
        for lid, lm in self.landmarks.items():
            if not lm.obs:
                bad.append(lid)
                continue
            age = rec.order - lm.first_order
            if lm.segment != rec.segment or age > p.recent_age_keyframes:
                continue
            if lm.found < p.min_found_ratio * lm.visible:
                bad.append(lid)
            elif age >= p.cull_age_keyframes and len(lm.obs) < p.min_observations:
                bad.append(lid)
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
        ids = sorted({lid for k in list(local) + list(fixed)
                      for lid in self.keyframes[k].landmark[self.keyframes[k].landmark >= 0].tolist()})
        pos = np.array([self.landmarks[i].position for i in ids], float).reshape(-1, 3)
        desc = np.array([self.landmarks[i].descriptor for i in ids], np.uint8).reshape(-1, 32)
        poses = {k: self.keyframes[k].T_world_cam.copy() for k in local}
        update = LocalMapUpdate(rec.index, np.asarray(ids, np.int64), pos, desc, poses)
        if self.params.use_lines:
            lids = sorted({lid for k in list(local) + list(fixed)
                           for lid in self.keyframes[k].line_landmark.tolist() if lid >= 0})
            update.line_ids = np.asarray(lids, np.int64)
            update.line_endpoints = np.array([self.lines[i].endpoints for i in lids], float).reshape(-1, 2, 3)
            update.line_descriptors = np.array([self.lines[i].descriptor for i in lids], np.uint8).reshape(-1, 32)
        return update
