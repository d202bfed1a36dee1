"""Typed parameters of the monocular pipeline (YAML section ``mono``).

Defaults are ORB-SLAM's monocular values (Mur-Artal et al., ORB-SLAM, T-RO 2015, §IV;
its Initializer / Tracking / LocalMapping sources): chi-square 95 % quantiles for the
two-view model scores (5.99 for the 2-DoF homography transfer error, 3.84 for the
1-DoF epipolar distance), 200 RANSAC iterations of 8 correspondences, a homography
when R_H = S_H / (S_H + S_F) > 0.45, at least 1 degree of parallax.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from shared.errors import ConfigError

CHI2_95_1DOF = 3.841
CHI2_95_2DOF = 5.991


@dataclass(frozen=True)
class MonoParams:
    # ORB features per frame; 0 = tracking.n_features. One camera needs denser corners than
    # stereo to initialise (ORB-SLAM initialises with twice its feature count): KITTI stereo
    # runs with 1600, its monocular initialisation failed with them (Sim(3) ATE 1.25 m on 15
    # frames against 0.036 m with 2000).
    n_features: int = 0
    # --- two-view initialisation (ORB-SLAM Initializer) --------------------------------
    ransac_iterations: int = 200
    sigma_px: float = 1.0                 # measurement sigma of the model scores (px)
    chi2_homography: float = CHI2_95_2DOF
    chi2_fundamental: float = CHI2_95_1DOF
    homography_ratio: float = 0.45        # R_H above which the homography is chosen
    min_parallax_deg: float = 1.0
    min_triangulated: int = 50            # good points a motion hypothesis must triangulate
    reprojection_chi2: float = 4.0        # squared px (x sigma^2) for a triangulated point
    ambiguity_ratio: float = 0.7          # second-best hypothesis must have fewer good points than this x best
    init_min_features: int = 100          # keypoints a frame needs to start / attempt initialisation
    init_min_matches: int = 100           # below this the reference frame is replaced
    init_search_radius: float = 100.0     # px, ORB-SLAM SearchForInitialization window
    init_max_hamming: int = 50            # ORB-SLAM TH_LOW
    init_ratio: float = 0.9
    init_max_frames: int = 30             # reference frame replaced after this many failed attempts
    init_min_map_points: int = 50         # ORB-SLAM: fewer tracked points after init = wrong init

    # --- tracking -----------------------------------------------------------------------
    search_radius: float = 15.0           # px, projection search with the motion model
    search_radius_wide: float = 30.0      # second attempt when the first finds too few
    search_radius_local: float = 4.0      # px at octave 0 (x scale), local-map search
    max_hamming: int = 75
    ratio: float = 0.8
    min_inliers: int = 20                 # below: frame lost (ORB-SLAM mono uses 30 after local map)
    lost_frames_to_reset: int = 5         # consecutive lost frames before the map restarts
    # with a relocaliser (the keyframe database, canopy.loop.mono.relocalise_mono) the map is
    # kept this long while every lost frame tries to relocalise (ORB-SLAM2 keeps it for good,
    # ORB-SLAM3 starts a new map). As long as without one by default: a failed relocalisation
    # costs these frames (KITTI 06 with frames 20-24 black, where relocalisation finds 6-16
    # descriptor matches after 5 m of forward motion and fails: 30 left the run lost for good,
    # 35 % tracked; 10 cost 5 frames, 74.5 % tracked; 5 as without a relocaliser, 84.3 %)
    reloc_lost_frames_to_reset: int = 5
    pose_rounds: int = 4
    pose_iterations: int = 10
    chi2_mono: float = CHI2_95_2DOF

    # --- keyframes (ORB-SLAM NeedNewKeyFrame, monocular) --------------------------------
    max_frames_between_keyframes: int = 10
    min_frames_between_keyframes: int = 0
    keyframe_tracked_ratio: float = 0.9   # inliers below this x the reference keyframe's points
    keyframe_min_inliers: int = 15

    # --- local mapping --------------------------------------------------------------------
    window_size: int = 10                 # local keyframes optimised by local BA
    covisible_for_triangulation: int = 10  # neighbour keyframes new points are triangulated with
    min_baseline_depth_ratio: float = 0.01  # skip pairs whose baseline / median depth is below
    triangulation_max_hamming: int = 50
    triangulation_ratio: float = 0.9      # best < ratio x second best along the epipolar band
    epipolar_chi2: float = CHI2_95_1DOF   # px^2 (x sigma^2) distance to the epipolar line
    fuse_radius: float = 3.0              # px at octave 0 (x scale): ORB-SLAM Fuse window
    fuse_ratio: float = 0.8               # best < ratio x second best in the window
    ba_iterations: int = 10
    ba_passes: int = 2
    huber: float = math.sqrt(CHI2_95_2DOF)
    min_found_ratio: float = 0.25
    cull_age_keyframes: int = 2
    min_observations: int = 2
    fixed_pose_sigma: float = 1e-6

    # --- loop closing in Sim(3) (ORB-SLAM ComputeSim3 / OptimizeEssentialGraph, monocular) --
    # the rest (detection, PnP verification, drift gate) is the stereo ``loop`` section
    loop_enabled: bool = True             # with --loop: close loops in mono too
    sim3_iterations: int = 200            # RANSAC iterations of Horn's 3-point similarity
    sim3_chi2: float = 9.210              # ORB-SLAM Sim3Solver: chi2 99 %, 2 DoF (x sigma^2 of the octave)
    sim3_min_inliers: int = 20            # ORB-SLAM: 20 inliers of the Sim3 RANSAC
    # 3D agreement of a Sim(3) inlier, relative to the point's distance: reprojection alone
    # cannot see a wrong depth when the two cameras are close (a revisit along the same path)
    sim3_max_relative_3d_error: float = 0.1
    sim3_max_rotation_disagreement_deg: float = 5.0  # Sim(3) rotation vs the PnP one
    loop_max_scale_change: float = 0.5    # a loop scale outside [1/(1+x), 1+x] is refused
    sigma_log_scale: float = 0.01         # pose-graph edges: log-scale sigma (rotation/translation: ``loop``)
    fuse_loop_neighbours: int = 10        # keyframes around each side whose points are fused after a loop

    def validate(self) -> "MonoParams":
        def need(ok: bool, name: str, what: str) -> None:
            if not ok:
                raise ConfigError("MonoParams", f"{name} {what} (got {getattr(self, name)!r})")

        need(self.n_features >= 0, "n_features", "must be >= 0 (0: tracking.n_features)")
        need(self.ransac_iterations >= 1, "ransac_iterations", "must be >= 1")
        need(self.sigma_px > 0, "sigma_px", "must be > 0")
        need(0 < self.homography_ratio < 1, "homography_ratio", "must be in (0, 1)")
        need(self.min_parallax_deg >= 0, "min_parallax_deg", "must be >= 0")
        need(self.min_triangulated >= 8, "min_triangulated", "must be >= 8")
        need(self.init_min_matches >= 8, "init_min_matches", "must be >= 8")
        need(self.min_inliers >= 6, "min_inliers", "must be >= 6")
        need(self.window_size >= 2, "window_size", "must be >= 2")
        need(self.max_frames_between_keyframes >= 1, "max_frames_between_keyframes", "must be >= 1")
        need(self.lost_frames_to_reset >= 1, "lost_frames_to_reset", "must be >= 1")
        need(self.reloc_lost_frames_to_reset >= 1, "reloc_lost_frames_to_reset", "must be >= 1")
        need(self.sim3_iterations >= 1, "sim3_iterations", "must be >= 1")
        need(self.sim3_min_inliers >= 3, "sim3_min_inliers", "must be >= 3")
        need(self.loop_max_scale_change > 0, "loop_max_scale_change", "must be > 0")
        need(self.sigma_log_scale > 0, "sigma_log_scale", "must be > 0")
        return self

    def __post_init__(self):
        self.validate()
