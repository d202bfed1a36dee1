"""What tracking measures of each landmark (a mixin of ``canopy.frontend.tracker.Tracker``):
far stereo points as bearing-only measurements (ORB-SLAM's ThDepth role,
``TrackingParams.stereo_obs_max_depth_baselines``), stereo points on occluding contours the
same way (``TrackingParams.contour_enabled``, ``canopy.frontend.stereo_silhouette``), and
ORB-SLAM's isInFrustum test of the local-map search (viewing angle and scale range,
``TrackingParams.view_max_angle_deg``).
The frame's stereo matches as pose refinement and landmark creation see them (``_stereo``,
``_landmark_candidates``, ``_close``) live here too. Uses the tracker's ``params``,
``scale_factors``, ``calib``, its ``_stereo_raw`` / ``_contour_inputs`` and its ``_stereo_obs_depth``, ``_silhouette``,
``_stereo_last`` / ``_stereo_obs``, ``_lm_normal`` / ``_lm_max_dist`` state.
"""
from __future__ import annotations

import os
import sys

import numpy as np

from canopy.enhance.noise import estimate_noise
from canopy.frontend.features import Features
from canopy.frontend.keypoint_uncertainty import disparity_sigma
from canopy.frontend.geometry import pose_information, project_stereo, stereo_pose_jacobian, transform
from canopy.frontend.stereo import StereoMatches
from canopy.frontend.stereo_silhouette import ContourParams, SilhouetteDetector
from canopy.frontend.tracker_vertical import with_attitude
from canopy.frontend.tracker_worker import StereoJob, record_stage as _stage, stage_clock as _clock

_MP_DEBUG = bool(os.environ.get("CANOPY_MOTION_PRIOR_DEBUG"))  # print the gate's rotation std per refinement


class TrackerMeasurementsMixin:
    """Bearing-only far points and the frustum test (see the module docstring)."""

    def _stereo_points_world(self, feats: Features, stereo: StereoMatches, T_wc: np.ndarray, idx: np.ndarray):
        z = stereo.depth[idx].astype(np.float64)
        u, v = feats.uv[idx, 0].astype(np.float64), feats.uv[idx, 1].astype(np.float64)
        Pc = np.stack([(u - self.calib.cx) * z / self.calib.fx, (v - self.calib.cy) * z / self.calib.fy, z], axis=1)
        return transform(T_wc, Pc)

    def _landmark_candidates(self, stereo: StereoMatches) -> np.ndarray:
        ok = stereo.valid if self.params.contour_landmarks else self._surface_stereo(stereo)
        uncertain = self._uncertain_mask(stereo)
        if uncertain is not None and not self.params.uncertain_stereo_landmarks:
            ok = ok & ~uncertain
        return ok & (stereo.depth < self._max_depth)

    def _close(self, stereo: StereoMatches) -> np.ndarray:
        return self._surface_stereo(stereo) & (stereo.depth < self._close_depth)

    def _stereo(self, stereo: StereoMatches | StereoJob, timings: dict) -> StereoMatches:
        """The frame's stereo matches, waiting for the worker's job if they are pending (its
        wait is the tracking thread's "stereo" stage); the first call also flags points on occluding
        contours (tracking.contour_*) and derives the matches pose refinement sees (far and
        contour points bearing only)."""
        if stereo is self._stereo_last:  # already this frame's (contour-flagged) matches
            return stereo
        if isinstance(stereo, StereoJob):
            t0 = _clock()
            job, stereo = stereo, stereo.result()
            if self._stereo_raw is not stereo:
                _stage(timings, "stereo", t0)
                timings.update(job.timings)
        if self._stereo_raw is not stereo:
            self._stereo_raw = stereo
            if self._silhouette is not None:  # occluding-contour points: monocular (stereo_silhouette)
                t0 = _clock()
                stereo = self._flag_contours(*self._contour_inputs, stereo)
                _stage(timings, "contour", t0)
            self._uncertain = (stereo, self._uncertain_stereo(stereo))
            self._noisy_far_mask = (stereo, self._noisy_far(stereo))
            self._stereo_last, self._stereo_obs = stereo, self._bearing_only_far(stereo)
        return self._stereo_last

    def _uncertain_mask(self, stereo: StereoMatches) -> np.ndarray | None:
        """The uncertain-disparity flags computed for exactly these stereo matches (None: none computed,
        the option off, or the frame under the noise gate)."""
        flagged = getattr(self, "_uncertain", None)  # set per frame in _stereo
        return flagged[1] if flagged is not None and flagged[0] is stereo else None

    def _frame_noise(self) -> float | None:
        """The current frame's robust noise sigma (the extractor's, else measured on the left image's lower
        half); None before the frame's images are known."""
        if self._contour_inputs is None:
            return None
        left_img, _, feats = self._contour_inputs
        noise = feats.robust_noise_sigma
        return estimate_noise(left_img, rows_fraction=0.5) if noise is None else noise

    def _noisy_far(self, stereo: StereoMatches) -> np.ndarray | None:
        """Stereo points beyond ``noisy_stereo_obs_max_depth_baselines`` on a frame whose robust noise sigma
        is at least ``uncertain_stereo_min_noise``; None when off or under the gate. On such frames far
        points' stereo depths pull the path long (s30-offset: the noisy sensor's online path 0.16-0.22 %
        longer than the clean frames' at the same calibration, while the whole map's BA gets the scale).
        Off by default: bimodal over noise draws (docs/notes/s30-offset.md)."""
        if not np.isfinite(self._noisy_stereo_obs_depth):
            return None
        noise = self._frame_noise()
        if noise is None or noise < self.params.uncertain_stereo_min_noise:
            return None
        return stereo.valid & (stereo.depth >= self._noisy_stereo_obs_depth)

    def _uncertain_stereo(self, stereo: StereoMatches) -> np.ndarray | None:
        """Stereo points whose relative Cramér-Rao disparity sigma is at least
        ``uncertain_stereo_max_rel_sigma`` on a frame whose robust noise sigma is at least
        ``uncertain_stereo_min_noise`` (canopy.frontend.keypoint_uncertainty.disparity_sigma); None
        when the option is off or the frame is under the noise gate (nothing changes)."""
        p = self.params
        if p.uncertain_stereo_max_rel_sigma <= 0 or self._contour_inputs is None:
            return None
        left_img, _, feats = self._contour_inputs
        noise = feats.robust_noise_sigma
        if noise is None:
            noise = estimate_noise(left_img, rows_fraction=0.5)
        if noise < p.uncertain_stereo_min_noise:
            return None
        idx = np.flatnonzero(stereo.valid)
        out = np.zeros(len(stereo.depth), bool)
        if len(idx):
            uv = feats.uv[idx].astype(np.float32)
            sd = disparity_sigma(left_img, uv, feats.octave[idx], self.scale_factors, noise, p.subpixel_window,
                                 p.uncertain_stereo_sampled_noise)
            disp = self.calib.bf / stereo.depth[idx].astype(np.float64)
            out[idx] = sd >= p.uncertain_stereo_max_rel_sigma * disp
        return out


    def _make_silhouette_detector(self) -> SilhouetteDetector | None:
        """The contour test of ``tracking.contour_*``; None when it is off."""
        if not self.params.contour_enabled:
            return None
        return SilhouetteDetector(ContourParams.from_tracking(self.params))

    def _flag_contours(self, left_img: np.ndarray, right_img: np.ndarray, feats: Features,
                       stereo: StereoMatches) -> StereoMatches:
        """``stereo`` with ``on_contour`` set for its matched keypoints (unchanged when off)."""
        if self._silhouette is None or not self._contour_turn_gate():
            return stereo
        on = np.zeros(len(stereo.depth), bool)
        idx = np.flatnonzero(stereo.valid)
        if len(idx):
            on[idx] = self._silhouette(left_img, right_img, feats.uv[idx].astype(np.float64), feats.octave[idx],
                                       self.params.scale_factor)
        return StereoMatches(stereo.u_right, stereo.depth, stereo.n_candidates, on_contour=on)

    def _contour_turn_gate(self) -> bool:
        """True when this frame gets the contour test: always with ``contour_min_rotation_deg`` 0,
        else only while the constant-velocity model (the last frame-to-frame motion) turns by at
        least that angle. The angle is the rotation's, trace(R) = 1 + 2 cos(angle)."""
        min_deg = self.params.contour_min_rotation_deg
        if min_deg <= 0:
            return True
        if not self._velocity_valid:
            return False
        c = 0.5 * (float(np.trace(self._velocity[:3, :3])) - 1.0)
        return bool(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))) >= min_deg)

    def _monocular_stereo(self, stereo: StereoMatches) -> np.ndarray:
        """Stereo points measured bearing-only: beyond the stereo measurement depth, or on an
        occluding contour (their disparity belongs to no 3D point)."""
        mono = stereo.valid & (stereo.depth >= self._stereo_obs_depth)
        if stereo.on_contour is not None:
            mono |= stereo.on_contour
        uncertain = self._uncertain_mask(stereo)
        if uncertain is not None and self.params.uncertain_stereo_bearing_only:
            mono |= uncertain  # disparity the image cannot pin (_uncertain_stereo)
        flagged = getattr(self, "_noisy_far_mask", None)  # set per frame in _stereo
        if flagged is not None and flagged[0] is stereo and flagged[1] is not None:
            mono |= flagged[1]  # far points of a noisy frame (_noisy_far)
        return mono

    def _bearing_only_far(self, stereo: StereoMatches) -> StereoMatches:
        """The measurements pose refinement and BA see: stereo points beyond the stereo
        measurement depth or on a contour lose their right-image column (monocular, bearing
        only); the depth of far points still initialises landmarks."""
        mono = self._monocular_stereo(stereo)
        if not mono.any():
            return stereo
        return StereoMatches(np.where(mono, -1.0, stereo.u_right).astype(np.float32),
                             np.where(mono, -1.0, stereo.depth).astype(np.float32), stereo.n_candidates,
                             on_contour=stereo.on_contour)

    def _keyframe_u_right(self, stereo: StereoMatches) -> np.ndarray:
        """Right-image columns for BA: -1 (monocular edge) beyond the stereo measurement depth
        and on contours."""
        return np.where(self._monocular_stereo(stereo), -1.0, stereo.u_right).astype(np.float32)

    def _surface_stereo(self, stereo: StereoMatches) -> np.ndarray:
        """Stereo points whose depth is a 3D point's: valid and not on a contour (landmark
        candidates, close points of the keyframe condition)."""
        if stereo.on_contour is None:
            return stereo.valid
        return stereo.valid & ~stereo.on_contour

    def _refine(self, T_cw, X, r, feats, stereo, inliers=None, line_obs=None):
        # far points as monocular measurements (see _bearing_only_far)
        obs = self._stereo_obs if stereo is self._stereo_last else stereo
        # tracking.motion_prior_sigma_*: the constant-velocity prediction joins as a pose prior
        prior = getattr(self, "_motion_prior", None)
        if prior is not None and (line_obs is not None or not self._measurements_weak(T_cw, X, r, feats, obs, inliers)):
            prior = None
        # tracking.vertical_track_prior / diagnose_pitch's oracle: the frame's measured up (tracker_vertical)
        prior = with_attitude(prior, getattr(self, "_attitude_term", None))
        # tracking.travel_direction_sigma_deg: the step across the rig's direction of travel (travel_direction)
        prior = with_attitude(prior, getattr(self, "_travel_term", None))
        return super()._refine(T_cw, X, r, feats, obs, inliers=inliers, line_obs=line_obs, extra=prior)

    def _measurements_weak(self, T_cw, X, r, feats, obs, inliers) -> bool:
        """tracking.motion_prior_min_rot_std_deg: the prior joins only when the matches' own
        rotation uncertainty at the starting pose (the largest standard deviation of the rotation
        block of (J^T Sigma^-1 J)^-1, the information refine_pose reports) reaches it; 0: always."""
        gate = self.params.motion_prior_min_rot_std_deg
        if gate <= 0 and not _MP_DEBUG:
            return True
        m = np.ones(len(X), bool) if inliers is None else inliers
        _, Pc = project_stereo(T_cw, X[m], self.calib)
        front = Pc[:, 2] > 1e-6
        info = pose_information(stereo_pose_jacobian(Pc[front], self.calib), self._sigma(feats.octave[r][m][front]),
                                obs.valid[r][m][front].astype(float))
        try:
            cov = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            return True
        rot_std = float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 0.0))))
        if _MP_DEBUG:
            print(f"MPDEBUG rot_std_deg {rot_std:.5f} n {int(front.sum())}", file=sys.stderr, flush=True)
        return rot_std >= gate

    def _record_viewing(self, ids: np.ndarray, pos: np.ndarray, centre: np.ndarray, octave: np.ndarray) -> None:
        """ORB-SLAM's MapPoint normal and max distance (UpdateNormalAndDepth) at creation:
        the unit ray from the creating camera, and distance x scale^octave."""
        if len(ids) == 0:
            return
        need = int(ids.max()) + 1
        if need > len(self._lm_max_dist):
            cap = max(need, 2 * len(self._lm_max_dist), 1024)
            self._lm_normal = np.concatenate([self._lm_normal, np.zeros((cap - len(self._lm_normal), 3))])
            self._lm_max_dist = np.concatenate([self._lm_max_dist, np.zeros(cap - len(self._lm_max_dist))])
        ray = pos - centre
        dist = np.linalg.norm(ray, axis=1)
        self._lm_normal[ids] = ray / np.maximum(dist, 1e-9)[:, None]
        self._lm_max_dist[ids] = dist * self.scale_factors[octave]

    def _in_frustum(self, T_wc: np.ndarray, ids: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """ORB-SLAM's isInFrustum beyond the image bounds: the landmark is seen within
        ``view_max_angle_deg`` of the direction it was created from and at a distance its
        descriptor's scale range covers (0.8 min .. 1.2 max). Landmarks this tracker did not
        create (a loaded map) pass."""
        p = self.params
        ok = np.ones(len(ids), bool)
        if p.view_max_angle_deg >= 180 or len(ids) == 0:
            return ok
        known = (ids >= 0) & (ids < len(self._lm_max_dist))
        k = np.flatnonzero(known)
        k = k[self._lm_max_dist[ids[k]] > 0]
        ray = pos[k] - T_wc[:3, 3]
        dist = np.linalg.norm(ray, axis=1)
        cos = np.einsum("ij,ij->i", ray, self._lm_normal[ids[k]]) / np.maximum(dist, 1e-9)
        dmax = self._lm_max_dist[ids[k]]
        dmin = dmax / self.scale_factors[-1]
        ok[k] = (cos >= np.cos(np.radians(p.view_max_angle_deg))) & (dist >= 0.8 * dmin) & (dist <= 1.2 * dmax)
        return ok
