"""Typed parameters of loop closing and relocalisation (YAML section ``loop``).

Defaults follow ORB-SLAM2's LoopClosing / KeyFrameDatabase (the open system AGRI §3.4
builds on, with DBoW3 in place of DBoW2): candidates scoring at least the worst
covisible neighbour, groups accumulating 0.75 of the best group score, three
consecutive consistent keyframes, and at least 40 inliers after refinement.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from shared.errors import ConfigError

CHI2_95_2DOF = 5.991
CHI2_95_3DOF = 7.815


@dataclass(frozen=True)
class LoopParams:
    enabled: bool = True
    vocabulary: str = ""                  # path of the ORB vocabulary ("" = the shipped default)
    # --- detection (ORB-SLAM DetectLoopCandidates) ------------------------------------------
    min_keyframes_since_loop: int = 10    # no detection right after a loop or at the start
    exclude_recent_keyframes: int = 20    # the latest keyframes are the same place, not a revisit
    # ... nor is a view a few metres back along the path: a loop is a return after driving away
    # (the generated orchard, 1.6 m/s, matches views 3 m apart in one lane with 5 cm errors)
    min_loop_path_m: float = 10.0
    covisibility_min_shared: int = 15     # landmarks two keyframes share to be covisible
    group_size: int = 10                  # best covisible neighbours forming a candidate's group
    # a candidate must score >= this x the lowest score of the query's covisible neighbours
    # (ORB-SLAM: 1). Below 1 lets a revisit under other light through: at dusk the true place
    # scores ~0.27, about as low as the dark neighbours themselves (dusk-loop --enhance auto:
    # 1 loop and ATE 0.061 -> 0.031 m at 0.8; day-loop unchanged, 0.028 m; no loop on KITTI/EuRoC)
    min_score_factor: float = 0.8
    min_common_words_ratio: float = 0.8   # of the best candidate's words shared with the query
    group_score_ratio: float = 0.75       # of the best accumulated group score
    consistency_keyframes: int = 3        # consecutive keyframes a candidate group must persist
    # PL-SLAM combined score: weight points / lines by their counts and image spread
    use_lines: bool = False
    # --- geometric verification (stereo PnP RANSAC, then motion-only refinement) -------------
    direct_index_levels_up: int = 2       # match features sharing a vocabulary node this many levels up
    max_hamming: int = 50                 # ORB-SLAM TH_LOW
    match_ratio: float = 0.75             # SearchByBoW's nearest / second nearest
    min_matches: int = 20                 # descriptor matches needed before RANSAC
    # hypotheses of the loop pose: "rigid" (3 matched stereo points, Horn's closed form, solved and
    # scored in one batch: canopy.loop.rigid_ransac) or "epnp" (cv2.solvePnPRansac, 5 points each)
    verify_ransac: str = "rigid"
    pnp_iterations: int = 300
    pnp_reprojection_error: float = 3.0   # px
    pnp_confidence: float = 0.999
    min_pnp_inliers: int = 20
    guided_search_radius: float = 10.0    # px, projecting the candidate's points with the PnP pose
    refine_rounds: int = 4
    refine_iterations: int = 10
    pixel_sigma: float = 1.0
    scale_factor: float = 1.2
    chi2_mono: float = CHI2_95_2DOF
    chi2_stereo: float = CHI2_95_3DOF
    min_inliers: int = 40                 # after guided search + refinement (ORB-SLAM: 40)
    # Keypoints tracking measures bearing-only (u_right -1: on an occluding contour,
    # tracking.contour_*, or beyond tracking.stereo_obs_max_depth_baselines) still carry their
    # stereo depth in the keyframe (it initialised their landmark), but a contour point's disparity
    # is that of no 3D point. True: the loop closer drops that depth, so verification's PnP and
    # refinement use them neither as candidate 3D points nor as stereo measurements of the query
    # (the refinement measured u_right -1 as a right-image column). Off: on the day-loop with
    # contour landmarks it halves the loop's matches (78 -> 37) for the same accuracy (loop pose
    # 0.5 / 0.3 cm, ATE 0.0197 m both ways; docs/notes/s8-drift.md)
    verify_stereo_only: bool = False
    # Odometry consistency (the idea of Kimera-RPGO's pairwise consistency check): a loop may
    # only correct what drift can have accumulated along the path between the two keyframes.
    # Orchard rows repeat (same trees every few metres), and a view of the next row or the
    # next tree can pass PnP with 40+ inliers; it then asks for a jump of metres.
    max_drift_per_metre: float = 0.015   # m of translation drift per metre travelled
    max_drift_floor_m: float = 0.25
    max_rot_drift_deg_per_metre: float = 0.2
    max_rot_drift_floor_deg: float = 3.0
    # --- pose graph (SE(3): stereo fixes the scale) ---------------------------------------
    essential_min_shared: int = 100       # covisibility edges of the essential graph (ORB-SLAM)
    odometry_sigma_rot: float = 0.01      # rad; relative poses from the map are precise
    odometry_sigma_trans: float = 0.01    # m
    loop_sigma_rot: float = 0.01
    loop_sigma_trans: float = 0.02
    robust_kernel_k: float = math.sqrt(CHI2_95_3DOF * 2)  # Huber width on whitened 6-d errors
    pgo_max_iterations: int = 50
    # --- full bundle adjustment after a loop (AGRI §3.4.2) ---------------------------------
    full_ba: bool = True
    full_ba_iterations: int = 10          # Levenberg-Marquardt iterations per pass
    full_ba_passes: int = 2               # robust pass, drop chi2 outliers, refine (ORB-SLAM GBA)
    full_ba_min_observations: int = 2     # a landmark seen once constrains no pose
    # the outlier test and the second pass use the pixel noise estimated from the first pass's
    # residuals (1.4826 MAD, full_ba.estimate_pixel_noise) instead of pixel_sigma, clamped to
    # [full_ba_noise_min_px, full_ba_noise_max_px] (day-loop: 0.35 px; the 1 px assumption kept
    # 3-sigma outliers in the second pass)
    full_ba_estimate_noise: bool = True
    full_ba_noise_min_px: float = 0.2
    full_ba_noise_max_px: float = 2.0
    # keyframes inserted while the full BA ran follow their spanning-tree parent's correction
    # (ORB-SLAM RunGlobalBundleAdjustment); off: the nearest older keyframe's
    full_ba_tree_corrections: bool = True
    # False: landmarks no keyframe measured in stereo (every observation bearing-only: contour
    # landmarks, tracking.contour_landmarks) stay out of the full BA and move with their reference
    # keyframe; their position is the stereo depth of a silhouette, no 3D point's (s8-drift)
    full_ba_bearing_only_landmarks: bool = True
    # their edges' pixel sigma times this when they are in it (a silhouette's bearings agree over
    # short baselines only): > 1 keeps their rotation information with less pull on the poses
    full_ba_bearing_only_sigma_factor: float = 1.0
    # landmark fusion across the loop (ORB-SLAM SearchAndFuse): candidate-side landmarks
    # projected into the query side's keyframes after the correction
    fuse: bool = True
    fuse_neighbours: int = 10             # best covisible keyframes on each side of the loop
    fuse_radius: float = 4.0              # px search window around the projection
    fuse_max_hamming: int = 50
    # False: only keypoints measured in stereo (u_right >= 0) take part in the fusion on either
    # side; a contour (bearing-only) landmark fused with a stereo keypoint across the loop gets a
    # stereo edge and is back in the full BA although its position is a silhouette's (s9-drift)
    fuse_bearing_only: bool = True
    # ORB-SLAM CorrectLoop order: the query side is first moved rigidly by the verified loop
    # pose, the duplicates are fused, and the keyframe pairs the fusion links across the loop
    # (>= loop_connection_min_shared fused landmarks) become extra loop edges of the pose graph
    fuse_before_pose_graph: bool = True
    loop_connection_min_shared: int = 15
    # --- process -------------------------------------------------------------------------
    # the loop closer's work (database query, verification, pose graph) runs in a worker thread,
    # and the full BA in a child process, at this nice value; the actor's own thread (messages,
    # heartbeat) keeps the normal priority (canopy.loop.worker, canopy.loop.priority). Its answers
    # are applied whenever they arrive, so it takes the cycles tracking and local mapping leave;
    # at the end of the stream it goes back to normal priority (0: no renicing)
    niceness: int = 19
    # and under SCHED_IDLE (Linux): a tracking thread that wakes preempts it at once; with the nice
    # value alone it waits for the worker's slice to end (canopy.loop.priority.set_thread_idle)
    sched_idle: bool = True
    # --- relocalisation -------------------------------------------------------------------
    reloc_min_inliers: int = 30
    reloc_candidates: int = 5             # database candidates tried per frame, best score first
    # after the motion-model bridge runs out, frames query the database this long before
    # tracking gives up and starts a new map segment (ORB-SLAM2 never gives up)
    reloc_max_frames: int = 50

    def validate(self) -> "LoopParams":
        def need(ok: bool, name: str, what: str) -> None:
            if not ok:
                raise ConfigError("LoopParams", f"{name} {what} (got {getattr(self, name)!r})")

        need(self.min_keyframes_since_loop >= 0, "min_keyframes_since_loop", "must be >= 0")
        need(self.min_loop_path_m >= 0, "min_loop_path_m", "must be >= 0")
        need(self.exclude_recent_keyframes >= 0, "exclude_recent_keyframes", "must be >= 0")
        need(self.covisibility_min_shared >= 1, "covisibility_min_shared", "must be >= 1")
        need(0 < self.min_score_factor <= 1, "min_score_factor", "must be in (0, 1]")
        need(self.group_size >= 1, "group_size", "must be >= 1")
        need(0 < self.min_common_words_ratio <= 1, "min_common_words_ratio", "must be in (0, 1]")
        need(0 < self.group_score_ratio <= 1, "group_score_ratio", "must be in (0, 1]")
        need(self.consistency_keyframes >= 1, "consistency_keyframes", "must be >= 1")
        need(self.direct_index_levels_up >= 0, "direct_index_levels_up", "must be >= 0")
        need(0 < self.max_hamming <= 256, "max_hamming", "must be in (0, 256]")
        need(0 < self.match_ratio <= 1, "match_ratio", "must be in (0, 1]")
        need(self.min_matches >= 4, "min_matches", "must be >= 4 (PnP)")
        need(self.min_pnp_inliers >= 4, "min_pnp_inliers", "must be >= 4")
        need(self.verify_ransac in ("rigid", "epnp"), "verify_ransac", "must be 'rigid' or 'epnp'")
        need(self.min_inliers >= self.min_pnp_inliers, "min_inliers", "must be >= min_pnp_inliers")
        need(self.pnp_reprojection_error > 0, "pnp_reprojection_error", "must be > 0")
        need(self.max_drift_per_metre >= 0 and self.max_drift_floor_m >= 0, "max_drift_per_metre",
             "and max_drift_floor_m must be >= 0")
        need(self.max_rot_drift_deg_per_metre >= 0 and self.max_rot_drift_floor_deg >= 0,
             "max_rot_drift_deg_per_metre", "and max_rot_drift_floor_deg must be >= 0")
        need(self.refine_rounds >= 1 and self.refine_iterations >= 1, "refine_rounds", "and refine_iterations must be >= 1")
        need(min(self.odometry_sigma_rot, self.odometry_sigma_trans, self.loop_sigma_rot,
                 self.loop_sigma_trans) > 0, "odometry_sigma_rot", "and all pose-graph sigmas must be > 0")
        need(self.robust_kernel_k > 0, "robust_kernel_k", "must be > 0")
        need(self.full_ba_iterations >= 1 and self.full_ba_passes >= 1, "full_ba_iterations",
             "and full_ba_passes must be >= 1")
        need(0 < self.full_ba_noise_min_px <= self.full_ba_noise_max_px, "full_ba_noise_min_px",
             "must be > 0 and <= full_ba_noise_max_px")
        need(self.full_ba_bearing_only_sigma_factor > 0, "full_ba_bearing_only_sigma_factor", "must be > 0")
        need(self.full_ba_min_observations >= 1, "full_ba_min_observations", "must be >= 1")
        need(self.fuse_neighbours >= 0, "fuse_neighbours", "must be >= 0")
        need(self.fuse_radius > 0, "fuse_radius", "must be > 0")
        need(self.loop_connection_min_shared >= 1, "loop_connection_min_shared", "must be >= 1")
        need(0 <= self.niceness <= 19, "niceness", "must be in [0, 19]")
        need(0 < self.fuse_max_hamming <= 256, "fuse_max_hamming", "must be in (0, 256]")
        need(self.reloc_min_inliers >= 4, "reloc_min_inliers", "must be >= 4")
        need(self.reloc_candidates >= 1, "reloc_candidates", "must be >= 1")
        need(self.reloc_max_frames >= 0, "reloc_max_frames", "must be >= 0")
        return self

    def __post_init__(self):
        self.validate()
