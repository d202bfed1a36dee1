"""Local bundle adjustment of ``LocalMapper`` in GTSAM (AGRI Eq. 8-11; ORB-SLAM's
LocalBundleAdjustment): stereo / monocular reprojection factors with Huber kernels on the
points, Eq. 10 line terms on two-endpoint line landmarks, outlier passes, write-back.

A mixin of ``canopy.backend.local_mapper.LocalMapper`` (uses its stores ``keyframes``,
``landmarks``, ``lines`` and ``params``).
"""
from __future__ import annotations

import gtsam
import numpy as np

from canopy.backend.attitude_prior import attitude_factors
from canopy.backend.line_factors import (line_custom_factor, line_endpoint_measurements, line_projection_factors,
                                         right_shift)
from canopy.backend.stereo_ba import StereoEdges, bundle_adjust_points, edge_chi2, projection_chi2
from canopy.backend.map_store import _sorted_unique_ids
from canopy.frontend.geometry import se3_inv
from shared.arrays import unique_sorted

X = gtsam.symbol_shorthand.X
L = gtsam.symbol_shorthand.L
EA = gtsam.symbol_shorthand.A  # line landmark start point
EB = gtsam.symbol_shorthand.B  # line landmark end point


class LocalBundleAdjustmentMixin:
    """Bundle adjustment over a local window (see the module docstring)."""

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

    def _bundle_adjust(self, local: list[int], fixed: list[int], scale: float, table=None) -> None:
        """Minimise AGRI Eq. 11 (point terms, Eq. 9) over the local keyframes and their landmarks.
        ``table``: the step's ``map_store.ObservationTable``, current (observations unchanged since read)."""
        p = self.params
        kf_set = set(local) | set(fixed)
        # edges: (kf, landmark, keypoint)
        lm_ids, e_kf, e_lm, e_kp = self._observation_edges(local, kf_set, table)
        lines = self._line_edges(local, kf_set) if p.use_lines else None
        if not lm_ids and (lines is None or len(lines[0]) == 0):
            return
        # every edge's keypoint by one gather from the window keyframes' arrays laid end to end
        # (one masked gather per keyframe cost ~2 ms per KITTI keyframe), the keyframes' offsets by a
        # lookup table over the frame indices and the rows by np.take (~8x cheaper than a fancy index
        # of 2-D rows; the same values)
        kf_ids = _sorted_unique_ids(e_kf)
        kfs = [self.keyframes[k] for k in kf_ids.tolist()]
        if kfs:
            row_of_kf = np.zeros(int(kf_ids[-1]) + 1, np.int64)
            row_of_kf[kf_ids] = np.cumsum([0] + [len(kf.uv) for kf in kfs])[:-1]
            row = row_of_kf[e_kf] + e_kp
            uv = np.take(np.concatenate([kf.uv for kf in kfs]).astype(float, copy=False), row, axis=0)
            ur = np.take(np.concatenate([kf.u_right for kf in kfs]).astype(float, copy=False), row)
            octv = np.take(np.concatenate([kf.octave for kf in kfs]).astype(np.int64, copy=False), row)
        else:
            uv, ur, octv = np.empty((0, 2)), np.empty(0), np.empty(0, np.int64)
        stereo = ur >= 0
        active = np.ones(len(e_kf), bool)
        if lines is None and p.ba_solver == "schur":
            self._bundle_adjust_schur(local, fixed, lm_ids, e_kf, e_lm, uv, ur, octv, stereo, scale)
            return
        values = gtsam.Values()
        for k in sorted(kf_set):
            values.insert(X(k), gtsam.Pose3(self.keyframes[k].T_world_cam))
        for lid in lm_ids:
            values.insert(L(lid), self.landmarks[lid].position)
        if lines is not None:
            l_kf, l_id, l_coef, l_right, l_seg = lines
            for lid in unique_sorted(l_id).tolist():
                values.insert(EA(lid), self.lines[lid].endpoints[0])
                values.insert(EB(lid), self.lines[lid].endpoints[1])
            # edges far off at the initial estimate stay out of the graph (their residual would
            # dominate the first LM steps) and are judged again after BA; l_out: outliers found
            # by a pass; l_active: usable edges of lines they still constrain
            l_gated = self._line_edge_chi2(values, l_kf, l_id, l_coef, l_right) > p.line_chi2_gate
            l_out = np.zeros(len(l_kf), bool)
        fixed_noise = gtsam.noiseModel.Isotropic.Sigma(6, p.fixed_pose_sigma)
        attitude = self._attitude_priors(local)
        for _ in range(p.ba_passes):
            graph = gtsam.NonlinearFactorGraph()
            for k in fixed:
                graph.add(gtsam.PriorFactorPose3(X(k), gtsam.Pose3(self.keyframes[k].T_world_cam), fixed_noise))
            if attitude is not None:
                for f in attitude_factors([X(local[i]) for i in attitude.pose.tolist()], attitude):
                    graph.add(f)
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
                                       l_right[l_active], l_seg[l_active])
            lm_params = gtsam.LevenbergMarquardtParams()
            lm_params.setMaxIterations(p.ba_iterations)
            lm_params.setRelativeErrorTol(p.ba_relative_tol)
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
            for lid in unique_sorted(l_id).tolist():
                self.lines[lid].endpoints = np.stack([np.asarray(values.atPoint3(EA(lid)), float),
                                                      np.asarray(values.atPoint3(EB(lid)), float)])
            judged = l_active | l_gated
            l_bad = l_out | (judged & (self._line_edge_chi2(values, l_kf, l_id, l_coef, l_right) > p.chi2_line))
            for j in np.flatnonzero(l_bad).tolist():
                self._remove_line_observation(int(l_id[j]), int(l_kf[j]), bool(l_right[j]))

    def _bundle_adjust_schur(self, local, fixed, lm_ids, e_kf, e_lm, uv, ur, octv, stereo, scale) -> None:
        """The points-only BA of ``_bundle_adjust`` with the numpy Schur-complement solver
        (``canopy.backend.stereo_ba``): same residuals, kernels, passes and outlier rules."""
        p = self.params
        poses = list(local) + list(fixed)
        T_cw = np.stack([se3_inv(self.keyframes[k].T_world_cam) for k in poses])
        lm_arr = np.asarray(lm_ids, np.int64)
        rows = getattr(self.landmarks, "rows", None)
        if rows is not None:   # the points by one gather from the store's rows (map_store.LandmarkStore)
            X = np.take(rows.pos, lm_arr, axis=0)
        else:
            lms = [self.landmarks[lid] for lid in lm_ids]
            # one concatenate of the small arrays (per-element Python over ~2 k points cost ~1 ms)
            X = np.concatenate([lm.position for lm in lms]).astype(float, copy=False).reshape(-1, 3) if lms \
                else np.zeros((0, 3))
        # the edges' pose indices by a lookup table over the keyframe indices (per-element Python
        # over ~7 k edges cost ~1 ms per KITTI keyframe)
        pose_lut = np.full(max(poses) + 1, -1, np.int64)
        pose_lut[poses] = np.arange(len(poses))
        pose_of_edge = pose_lut[e_kf]
        point_of_edge = np.searchsorted(lm_arr, e_lm)
        meas = np.column_stack([uv, np.where(stereo, ur, 0.0)])
        sigma = p.pixel_sigma * scale ** octv.astype(float)
        huber = np.where(stereo, p.huber_stereo, p.huber_mono)
        thr = np.where(stereo, p.chi2_stereo, p.chi2_mono)
        active = np.ones(len(e_kf), bool)
        attitude = self._attitude_priors(local)   # local keyframes are poses 0..len(local)-1
        all_edges = StereoEdges(pose_of_edge, point_of_edge, meas, stereo, sigma, huber)
        for _ in range(p.ba_passes):
            a = np.flatnonzero(active)
            edges = all_edges.take(a)
            final = []
            T_cw, X, _ = bundle_adjust_points(T_cw, len(local), X, edges, self.calib, p.ba_iterations,
                                              final_projection=final, relative_tol=p.ba_relative_tol,
                                              attitude=attitude)
            # the last pass's test is at the final estimate: it also decides the write-back below.
            # When the pass had every edge, LM's own projection at its result is that of all_edges
            # (same arrays, per-edge arithmetic): no second projection
            if final and len(a) == len(active):
                over = projection_chi2(*final[0], sigma, p.min_depth) > thr
            else:
                over = edge_chi2(T_cw, X, all_edges, self.calib, p.min_depth) > thr
            if not (active & over).any():
                break
            active &= ~over
        for i, k in enumerate(local):
            self.keyframes[k].T_world_cam = se3_inv(T_cw[i])
        if rows is not None:
            rows.pos[lm_arr] = X
        else:
            for lm, x in zip(lms, X):   # rows of the BA's own result array (nothing writes positions in place)
                lm.position = x
        bad = ~active | over
        for j in np.flatnonzero(bad).tolist():
            self._remove_observation(int(e_lm[j]), int(e_kf[j]))

    def _attitude_priors(self, local: list[int]):
        """The attitude prior terms of the local keyframes (mapping.attitude_prior; None when off or none)."""
        store = getattr(self, "attitude", None)
        if not self.params.attitude_prior or store is None:
            return None
        return store.priors(local)

    # ----------------------------------------------------------------- line terms (Eq. 10)
    def _line_edges(self, local: list[int], kf_set: set[int]):
        """Line edges of the lines seen by the local keyframes: (keyframe, line id, line
        coefficients, right image?) for every observation in ``kf_set``. A line enters BA when
        ``line_ba_min_keyframes`` keyframes of the window observe it (a line seen by one keyframe
        only constrains no pose, it only adds two free endpoints) and one of them in the right
        image too: left views alone leave the endpoints' depth free when the camera stands still
        or moves in the line's plane, an indeterminate system that LM only damps, slowly."""
        ids = sorted({lid for k in local for lid in self.keyframes[k].line_landmark.tolist() if lid >= 0})
        e_kf, e_id, e_coef, e_right, e_seg = [], [], [], [], []
        for lid in ids:
            for k, j in self.lines[lid].obs.items():
                if k not in kf_set:
                    continue
                kf = self.keyframes[k]
                e_kf.append(k)
                e_id.append(lid)
                e_coef.append(kf.line_coeffs[j])
                e_right.append(False)
                e_seg.append(kf.line_segments[j])
                if np.isfinite(kf.line_coeffs_right[j]).all():
                    e_kf.append(k)
                    e_id.append(lid)
                    e_coef.append(kf.line_coeffs_right[j])
                    e_right.append(True)
                    e_seg.append(kf.line_segments_right[j])
        edges = (np.asarray(e_kf, np.int64), np.asarray(e_id, np.int64), np.asarray(e_coef, float).reshape(-1, 3),
                 np.asarray(e_right, bool), np.asarray(e_seg, float).reshape(-1, 4))
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

    def _add_line_factors(self, graph, values, l_kf, l_id, l_coef, l_right, l_seg) -> None:
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
        A = np.array([values.atPoint3(EA(lid)) for lid in l_id.tolist()], float).reshape(-1, 3)
        B = np.array([values.atPoint3(EB(lid)) for lid in l_id.tolist()], float).reshape(-1, 3)
        meas, infos = line_endpoint_measurements(T, A, B, l_coef, l_seg, self.calib, l_right, p.line_sigma,
                                                 p.line_sigma_along)
        for which, key in ((0, EA), (1, EB)):
            for f in line_projection_factors([X(k) for k in l_kf.tolist()], [key(lid) for lid in l_id.tolist()],
                                             meas[which], infos, l_right, self._Kmono, self.calib, p.huber_line):
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
        kfs, kf_inv = np.unique(e_kf, return_inverse=True)
        T_cw = np.stack([se3_inv(values.atPose3(X(k)).matrix()) for k in kfs.tolist()])
        uniq, inv = np.unique(e_lm, return_inverse=True)
        P = np.array([values.atPoint3(L(l)) for l in uniq.tolist()], float).reshape(-1, 3)[inv]
        Pc = np.einsum("nij,nj->ni", T_cw[kf_inv, :3, :3], P) + T_cw[kf_inv, :3, 3]
        z = Pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.calib.fx * Pc[:, 0] / z + self.calib.cx
            v = self.calib.fy * Pc[:, 1] / z + self.calib.cy
            urp = u - self.calib.bf / z
        err = (uv[:, 0] - u) ** 2 + (uv[:, 1] - v) ** 2 + np.where(stereo, (ur - urp) ** 2, 0.0)
        chi2 = err / (self.params.pixel_sigma * scale ** octv) ** 2
        chi2[~(z > self.params.min_depth)] = np.inf
        return chi2

