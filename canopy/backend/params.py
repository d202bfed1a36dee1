"""Typed parameters of local mapping (YAML section ``mapping``)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from shared.errors import ConfigError

CHI2_95_2DOF = 5.991  # chi-square 95% quantiles (ORB-SLAM's outlier tests)
CHI2_95_3DOF = 7.815


@dataclass(frozen=True)
class MappingParams:
    window_size: int = 8                 # local keyframes optimised by local BA (AGRI §3.3.2)
    # neighbours whose view is within this many pixels of a keyframe already in the window add no
    # geometry and stay fixed (canopy.backend.still_window); 0: off (ORB-SLAM's window)
    window_min_view_change_px: float = 0.0
    # at most this many fixed keyframes in local BA, the best covisible with the window's landmarks (0: all,
    # ORB-SLAM's), and a landmark's distinctive descriptor from its newest descriptor_max_observations
    # observations (0: all). Both bound local mapping's cost per keyframe on a still camera
    # (canopy.backend.still_window, docs/notes/s15-stillcost.md)
    window_max_fixed: int = 0
    descriptor_max_observations: int = 0
    # ORB-SLAM's KeyFrameCulling (canopy.backend.keyframe_culling): after local BA, a covisible keyframe whose
    # landmarks are more than keyframe_culling_redundancy seen by keyframe_culling_observers other keyframes at
    # the same or a finer scale goes; the newest keyframe_culling_keep_recent keyframes are never culled.
    # Off: no keyframe is ever removed (bit-identical)
    keyframe_culling: bool = False
    keyframe_culling_redundancy: float = 0.9
    keyframe_culling_observers: int = 3
    keyframe_culling_keep_recent: int = 0
    covisibility_min_shared: int = 15    # landmarks two keyframes must share to be neighbours
    ba_iterations: int = 10              # Levenberg-Marquardt iterations per BA pass
    ba_passes: int = 2                   # ORB-SLAM: robust pass, drop outliers, refine again
    # LM stops when a step lowers the robust cost by less than this fraction (GTSAM's default
    # relativeErrorTol 1e-5). KITTI sets 1e-2 (configs/kitti.yaml): there the first step takes
    # 15-75 % off the cost, the second ~0.2 %, the third and fourth < 0.01 % (recorded BA calls)
    ba_relative_tol: float = 1e-5
    # points-only BA solver: "schur" (canopy.backend.stereo_ba: numpy, landmarks eliminated onto
    # the local poses, ~5x cheaper) or "gtsam" (one factor per observation). With use_lines the
    # GTSAM graph is always used (the line terms live there).
    ba_solver: str = "schur"
    pixel_sigma: float = 1.0             # px at octave 0; sigma = pixel_sigma * scale**octave
    huber_stereo: float = math.sqrt(CHI2_95_3DOF)  # robust kernel widths (whitened units)
    huber_mono: float = math.sqrt(CHI2_95_2DOF)
    chi2_stereo: float = CHI2_95_3DOF    # observation outlier thresholds after BA
    chi2_mono: float = CHI2_95_2DOF
    min_observations: int = 2            # keyframes that must see a landmark once it is old enough
    cull_age_keyframes: int = 2          # keyframes after creation before the test above applies
    recent_age_keyframes: int = 3        # older landmarks have survived and are no longer culled so
    min_found_ratio: float = 0.25        # found / visible (ORB-SLAM MapPointCulling)
    min_depth: float = 0.05              # m; landmarks behind or on a camera are dropped
    fixed_pose_sigma: float = 1e-6       # prior sigma holding fixed keyframes (rad, m)
    # s30: at the end of the run, one bundle adjustment of the whole map (every keyframe but the first and
    # every landmark; canopy.backend.final_ba) before the trajectory is written. Off: the written trajectory
    # is the online one, as ORB-SLAM3's without a loop (docs/notes/s30-offset.md).
    final_ba: bool = False
    # --- line landmarks in local BA (AGRI Eq. 10-11; issue 4) ---------------------------
    # Off: points-only BA, unchanged. On: each line landmark is two Point3 endpoints; every
    # observation adds Eq. 10 (distances of the projected endpoints to the observed infinite
    # line; also in the right image where the keyframe matched the line in stereo).
    use_lines: bool = False
    line_max_growth: float = 1.0        # a new observation may extend a line landmark by at most this x its length
    # "projection": one GenericProjectionFactor per endpoint whose measurement is the observed
    # segment's nearer endpoint (line_factors.line_endpoint_measurements), with a noise model
    # tight along the line normal (line_sigma: Eq. 10) and loose along the line
    # (line_sigma_along), which keeps the landmark's extent where the images see it instead of
    # letting the endpoints drift along the 3D line; it runs in C++. "custom": gtsam.CustomFactor
    # with the exact Eq. 10 residual only (extent free) and analytic Jacobians (Python callback).
    line_factor: str = "projection"
    line_sigma: float = 1.0              # px, per endpoint-to-line distance
    line_sigma_along: float = 40.0       # px, endpoint along the observed line ("projection" only)
    huber_line: float = math.sqrt(CHI2_95_2DOF)
    chi2_line: float = CHI2_95_2DOF      # line observation outlier threshold after BA
    line_min_observations: int = 2       # keyframes that must see a line once it is old enough
    # lines enter local BA once this many keyframes of the window observe them, one of them in
    # the right image too (1: also lines seen by one stereo keyframe only, which constrain no
    # pose and only add variables; left views alone leave the depth free for a still camera)
    line_ba_min_keyframes: int = 2
    # line observations farther than this (chi2, line_sigma units, both endpoints) from the
    # initial estimate are outliers before BA starts (400: ~14 px at each endpoint)
    line_chi2_gate: float = 400.0
    # True: line outliers found after a pass trigger another pass, as point outliers do.
    # False: they are dropped after BA (the Huber kernel bounded their pull on the poses)
    line_outliers_repeat_pass: bool = False
    # LM stops when an iteration lowers the cost by less than this fraction (GTSAM's default
    # 1e-5 stays for points only): Huber-weighted line outliers make the cost creep down by
    # ~1e-4 per iteration for many iterations without moving the estimate measurably
    line_ba_relative_error_tol: float = 1e-3
    # --- new landmarks triangulated across keyframes (canopy.backend.triangulation) -----
    # ORB-SLAM LocalMapping::CreateNewMapPoints: the new keyframe's keypoints without a landmark
    # matched (epipolar band, Hamming best of two) with the free keypoints of its
    # triangulate_covisible best covisible keyframes at least triangulate_min_baseline x the
    # rig's baseline away, triangulated and kept when they pass parallax, depth, reprojection and
    # scale checks. Off: stereo landmarks only, bit-identical.
    triangulate_new_points: bool = False
    triangulate_covisible: int = 6
    triangulate_min_baseline: float = 1.0      # x calib.baseline (ORB-SLAM stereo: baseline < mb skips)
    triangulate_max_hamming: int = 50          # ORB-SLAM TH_LOW
    triangulate_ratio: float = 0.9             # best < ratio x second best in the band
    triangulate_epipolar_chi2: float = 3.841   # px^2 (x sigma^2), 1-DoF 95 %
    triangulate_min_parallax_deg: float = 0.0  # 0: ORB-SLAM's cos < 0.9998 (~1.15 deg) only
    # only keypoints without a valid stereo depth (right match lost or never found) are
    # triangulated: a stereo depth tracking made no landmark of is an occluding contour's
    triangulate_skip_stereo: bool = True
    # a triangulated landmark must be seen by this many keyframes once cull_age_keyframes old
    # (ORB-SLAM MapPointCulling: cnThObs 3 for stereo maps; it starts with two)
    triangulate_min_observations: int = 3
    triangulate_id_base: int = 1 << 20         # the mapper's own landmark ids (tracking counts from 0)
    # --- confirmation of triangulated landmarks (canopy.backend.point_confirmation) -------
    # ORB-SLAM's SearchInNeighbors / Fuse in the mapper: each new keyframe is searched for the
    # triangulated landmarks still short of triangulate_min_observations, and the new keyframe's
    # triangulated landmarks are searched for in its triangulate_fuse_neighbours best covisible
    # keyframes. Off: bit-identical.
    triangulate_fuse: bool = False
    triangulate_fuse_neighbours: int = 6
    # a triangulated landmark found on a keypoint that has a landmark already duplicates it: True
    # moves its observations to that landmark (MapPoint::Replace), False only drops it
    triangulate_fuse_merge: bool = True
    # tracking's local map leaves out triangulated landmarks seen by fewer than
    # triangulate_min_observations keyframes (s14: tracking using them early is what hurt)
    triangulate_confirm: bool = False
    # local BA uses the unconfirmed ones meanwhile (False: confirmed ones only)
    triangulate_confirm_ba: bool = True
    # --- attitude prior (canopy.backend.attitude_prior; docs/notes/s25-attitude.md) ---------
    # local BA adds a 2-D prior on the pitch and roll of each local keyframe whose KeyframeData carries a
    # measured up (up_cam; tracking.vertical_estimate measures it), against the segment's reference: the
    # sigma-weighted mean of R_world_cam up_cam over its first attitude_reference_keyframes keyframes that
    # carry one. Off: bit-identical.
    attitude_prior: bool = False
    attitude_reference_keyframes: int = 1

    def validate(self) -> "MappingParams":
        def need(ok: bool, name: str, what: str) -> None:
            if not ok:
                raise ConfigError("MappingParams", f"{name} {what} (got {getattr(self, name)!r})")

        need(self.window_size >= 2, "window_size", "must be >= 2")
        need(self.window_min_view_change_px >= 0, "window_min_view_change_px", "must be >= 0")
        need(self.window_max_fixed >= 0, "window_max_fixed", "must be >= 0 (0: all)")
        need(self.descriptor_max_observations == 0 or self.descriptor_max_observations >= 3,
             "descriptor_max_observations", "must be 0 (all) or >= 3")
        need(0 < self.keyframe_culling_redundancy <= 1, "keyframe_culling_redundancy", "must be in (0, 1]")
        need(self.keyframe_culling_observers >= 1, "keyframe_culling_observers", "must be >= 1")
        need(self.keyframe_culling_keep_recent >= 0, "keyframe_culling_keep_recent", "must be >= 0")
        need(self.covisibility_min_shared >= 1, "covisibility_min_shared", "must be >= 1")
        need(self.ba_iterations >= 1, "ba_iterations", "must be >= 1")
        need(self.ba_passes >= 1, "ba_passes", "must be >= 1")
        need(self.ba_solver in ("schur", "gtsam"), "ba_solver", "must be 'schur' or 'gtsam'")
        need(self.pixel_sigma > 0, "pixel_sigma", "must be > 0")
        need(self.huber_stereo > 0 and self.huber_mono > 0, "huber_stereo", "and huber_mono must be > 0")
        need(self.chi2_stereo > 0 and self.chi2_mono > 0, "chi2_stereo", "and chi2_mono must be > 0")
        need(0 < self.ba_relative_tol < 1, "ba_relative_tol", "must be in (0, 1)")
        need(self.min_observations >= 1, "min_observations", "must be >= 1")
        need(self.cull_age_keyframes >= 1, "cull_age_keyframes", "must be >= 1")
        need(self.recent_age_keyframes >= self.cull_age_keyframes, "recent_age_keyframes",
             "must be >= cull_age_keyframes")
        need(0 <= self.min_found_ratio <= 1, "min_found_ratio", "must be in [0, 1]")
        need(self.min_depth > 0, "min_depth", "must be > 0")
        need(self.fixed_pose_sigma > 0, "fixed_pose_sigma", "must be > 0")
        need(self.line_factor in ("projection", "custom"), "line_factor", "must be 'projection' or 'custom'")
        need(self.line_sigma > 0 and self.line_sigma_along > 0, "line_sigma", "and line_sigma_along must be > 0")
        need(self.line_max_growth >= 0, "line_max_growth", "must be >= 0")
        need(self.huber_line > 0 and self.chi2_line > 0, "huber_line", "and chi2_line must be > 0")
        need(self.line_min_observations >= 1, "line_min_observations", "must be >= 1")
        need(self.line_ba_min_keyframes >= 1, "line_ba_min_keyframes", "must be >= 1")
        need(self.line_chi2_gate >= self.chi2_line, "line_chi2_gate", "must be >= chi2_line")
        need(0 < self.line_ba_relative_error_tol < 1, "line_ba_relative_error_tol", "must be in (0, 1)")
        need(self.triangulate_covisible >= 1, "triangulate_covisible", "must be >= 1")
        need(self.triangulate_min_baseline >= 0, "triangulate_min_baseline", "must be >= 0")
        need(0 <= self.triangulate_max_hamming <= 256, "triangulate_max_hamming", "must be in [0, 256]")
        need(0 < self.triangulate_ratio <= 1, "triangulate_ratio", "must be in (0, 1]")
        need(self.triangulate_epipolar_chi2 > 0, "triangulate_epipolar_chi2", "must be > 0")
        need(0 <= self.triangulate_min_parallax_deg < 90, "triangulate_min_parallax_deg", "must be in [0, 90)")
        need(self.triangulate_min_observations >= 2, "triangulate_min_observations", "must be >= 2")
        need(self.triangulate_id_base >= 1, "triangulate_id_base", "must be >= 1")
        need(self.triangulate_fuse_neighbours >= 0, "triangulate_fuse_neighbours", "must be >= 0")
        need(self.attitude_reference_keyframes >= 1, "attitude_reference_keyframes", "must be >= 1")
        return self

    def __post_init__(self):
        self.validate()
