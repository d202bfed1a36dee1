"""Typed parameters of the tracking front end (one frozen dataclass, YAML section ``tracking``).

Defaults follow ORB-SLAM2's stereo settings and AGRI-SLAM §3.2 (entropy-ratio
threshold α = 0.8 of Eq. 7). Build from YAML with
``shared.params.params_from_mapping(TrackingParams, section, source)``.
"""
from __future__ import annotations

from dataclasses import dataclass

from canopy.frontend.params_checks import validate_tracking_params


@dataclass(frozen=True)
class TrackingParams:
    # --- ORB extraction (AGRI §3.2.1; ORB-SLAM2 ORBextractor defaults) -------------
    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 20
    edge_threshold: int = 19            # border (px) where ORB cannot describe a corner
    patch_size: int = 31                # ORB descriptor patch (px)
    # Grid bucketing: detect n_features * oversample corners, then keep the strongest
    # ones cell by cell so that features spread over the image (ORB-SLAM's grid idea).
    # Extract the right image's ORB in a worker thread while the left one runs here:
    # OpenCV releases the GIL, so on 2 cores the two images cost about one.
    parallel_extraction: bool = True
    # With parallel_extraction: the worker also matches stereo (right ORB, then the band search and
    # SAD refinement against the left features) while this thread searches the local map with the
    # left features; identical results (canopy.frontend.tracker_worker). Not with lines (their jobs
    # share the worker).
    parallel_stereo: bool = True
    # OpenCV's own thread pool in the tracking process (cv2.setNumThreads, set by the tracking
    # actor when > 0; 0 leaves OpenCV's default, one thread per core). 1 (each OpenCV call on its
    # caller) looked better in process at load 15-19 (the tracking thread's blocked time per KITTI
    # frame 4.5 -> 1.4 ms p50, its stereo wait 5.7 -> 3.9 ms) but not through the actors at load ~7
    # (3 alternating runs each: blocked 11.9 -> 16.5 ms, stereo wait mean 8.7 -> 10.7 ms, 12.7 vs
    # 12.5 frames/s): the pool helps the worker when a core is free. Same results either way
    # (docs/notes/s10-speedfront.md); a quiet-machine bench_peers run decides.
    opencv_threads: int = 0
    # Python's GIL hand-over interval in the tracking process (sys.setswitchinterval, ms; 0 keeps
    # Python's 5 ms): the tracking thread and the stereo worker both run numpy / Python between
    # their OpenCV calls, and a thread asking for the GIL waits up to the interval for the other to
    # hand it over. Results are the same at any value (each thread's arithmetic is its own).
    # docs/notes/s16-fps.md
    switch_interval_ms: float = 0.0
    grid_cols: int = 16
    grid_rows: int = 8
    oversample: float = 1.6
    # OpenCV reports a level-L keypoint at x_L * s, the pyramid (cv2.resize) puts it at
    # (x_L + 0.5) s - 0.5: shift keypoints by 0.5 (s - 1) px (canopy.frontend.keypoint_centres)
    centre_level_keypoints: bool = False
    # Which extractor: "opencv" (cv2.ORB, one FAST threshold, Harris ranking, grid bucketing above)
    # or "cells" (canopy.frontend.cell_extractor: ORB-SLAM's ORBextractor -- FAST per ~cell_size px
    # cell at fast_threshold, again at fast_fallback_threshold in cells that found none, quadtree
    # distribution to per-level quotas; keeps low-contrast corners that one threshold loses).
    extractor: str = "opencv"
    # Frames the enhancement changed (the AFE FAST rule is passed: its own adaptive threshold and
    # Eq. 19 fallback) use this extractor: "opencv" or "cells".
    extractor_enhanced: str = "opencv"
    # ... with extractor "cells" and extractor_enhanced "opencv": an enhanced image on which AFE's
    # Eq. 18 threshold finds at least enhanced_cells_min_corners FAST corners goes to the cells
    # extractor anyway, its fallback at least enhanced_cells_noise_factor x the image's noise sigma
    # (0: off; canopy.frontend.enhanced_extractor). The presets' NoiseGatedExtractor follows the same
    # rule when > 0 (measured there and not used: docs/notes/s12-dark.md, second task)
    enhanced_cells_min_corners: int = 0
    enhanced_cells_noise_factor: float = 4.0
    # the corner count's moving average over the sequence: the newest image's weight (1: no smoothing)
    enhanced_cells_corner_weight: float = 1.0
    cell_size: int = 30                 # px (ORB-SLAM's W = 30)
    fast_fallback_threshold: int = 7    # ORB-SLAM's minThFAST, in cells where fast_threshold finds none
    # ... but never below this many sigmas of the image's noise (track_health.image_noise_sigma,
    # measured when fast_noise_factor > 0), so that the fallback does not pick up noise
    cell_fallback_noise_factor: float = 2.0
    # which corner of a quadtree node is kept: "fast" (ORB-SLAM: best FAST score per node),
    # "harris" (best Harris response per node), "harris2x" (quadtree to twice the quota on FAST
    # scores, the quota's strongest Harris responses of those, as cv2.ORB ranks). On KITTI 06 with
    # haze beta 0.06 and the noisy sensor: fast 100 % tracked, harris 98 %, harris2x 96 % and
    # 74 % (docs/notes/s6-cells.md)
    cell_ranking: str = "fast"

    # --- stereo matching on rectified rows (AGRI §3.2.2; ORB-SLAM2 ComputeStereoMatches)
    # How each left keypoint's right-image column is found: "descriptor" (the right image's ORB, row
    # band search, Hamming ratio test; canopy.frontend.stereo) or "flow" (pyramidal Lucas-Kanade from
    # the left keypoints into the right image with a row / disparity / back-track check, no right ORB;
    # canopy.frontend.stereo_flow, as VINS-Fusion's stereo tracking). Both end in the same SAD
    # sub-pixel refinement and SAD outlier test.
    stereo_matcher: str = "descriptor"
    # LK window (px, odd) and pyramid levels above level 0 (reach ~window/2 * 2^levels px); at most
    # flow_iterations Gauss-Newton steps per level (or a step < 0.03 px). VINS-Fusion tracks ~150
    # points with 21x21, 3 levels, 30 steps; for KITTI's 2000 keypoints that costs 70-95 ms CPU, 9x9
    # with 10 steps 12-18 ms and lands as often within 3 px of the descriptor match (97 %): the SAD
    # refinement fixes the column from there (docs/notes/s11-speed.md)
    flow_window: int = 9
    flow_levels: int = 3
    flow_iterations: int = 10
    flow_max_dy: float = 1.0            # |v_right - v_left| allowed after the flow, px (rectified rows)
    # LK drops a point whose window's gradient matrix has a smaller eigenvalue (per pixel, grey levels
    # scaled to [0,1]) than this: ill-conditioned, textureless windows. OpenCV's default 1e-4.
    flow_min_eig: float = 1e-4
    # right->left back-track must return within flow_back_px (0: no back-track); it starts at the
    # keypoint and runs on flow_back_levels pyramid levels (0: level 0 only, the cheap local check).
    # Neither 1.0 nor 0.5 px keeps every KITTI grid check the descriptor matcher passes (each loses
    # two different cells; docs/notes/s11-speed.md): the flow matcher is not a default anywhere.
    flow_back_px: float = 0.5
    flow_back_levels: int = 0
    stereo_max_hamming: int = 75        # (TH_HIGH + TH_LOW) / 2 of ORB-SLAM2
    stereo_ratio: float = 0.8           # best / second-best Hamming distance
    min_disparity: float = 0.5          # px; farther points carry no depth
    max_disparity_fraction: float = 0.5 # max disparity as a fraction of the image width
    row_tolerance: float = 2.0          # px at octave 0, scaled by scale_factor**octave
    octave_tolerance: int = 1           # right keypoint may sit one pyramid level away
    subpixel_window: int = 5            # half size of the SAD patch (11x11 as ORB-SLAM2)
    subpixel_search: int = 5            # SAD search +/- px around the descriptor match
    # What each SAD patch has subtracted (canopy.frontend.stereo.subpixel_refine): "centre", its
    # centre pixel (ORB-SLAM2), or "mean" (zero-mean SAD; the centre pixel's noise shifts the whole
    # patch, which on hazy noisy frames puts a third of the matches > 1 px off)
    subpixel_normalise: str = "centre"
    sad_outlier_factor: float = 2.1     # reject SAD > factor * median (1.5 * 1.4 in ORB-SLAM2)
    # ... on hazy / noisy frames a stricter factor (canopy.frontend.noisy_features): the factor falls
    # linearly from sad_outlier_factor to sad_outlier_factor_noisy as the frame's matching SNR (median
    # SAD per pixel / image noise sigma) falls from sad_snr_high to sad_snr_low. A noisy factor at or above sad_outlier_factor: off.
    # Off by default: it halves the ATE of hazy noisy KITTI (1.5) but the SNR measure does not tell
    # the generated orchard's clean frames (SNR ~1.5, fine texture in the sigma estimate) from
    # haze, and day-loop loses 7.4 -> 11.3 mm (docs/notes/s4-dark.md).
    sad_outlier_factor_noisy: float = 2.1
    sad_snr_low: float = 1.5
    sad_snr_high: float = 4.5
    # Constant disparity offset of the rectified rig, px: d_true = d_measured + disparity_offset_px
    # (a right principal point off by a fraction of a pixel). Measure it without ground truth with
    # benchmarks/calibrate_disparity_offset.py (canopy.frontend.disparity_offset).
    disparity_offset_px: float = 0.0
    # ... the same for keypoints of the "cells" extractor (its own sub-pixel localisation; the
    # offset is chosen per frame by the extractor that found the left keypoints, Features.extractor)
    disparity_offset_cells_px: float = 0.0

    # --- temporal matching against the local map -----------------------------------
    # Stage 1 (ORB-SLAM TrackWithMotionModel): project the local map with the constant-velocity
    # prediction and search a circle; widen once when too few; without a usable prediction,
    # brute-force descriptor matching (TrackReferenceKeyFrame's role; ratio test + RANSAC).
    search_radius: float = 10.0         # px around the predicted projection
    search_radius_wide: float = 40.0    # second attempt when the first finds too few
    # When EPnP RANSAC finds no pose on the window matches and there is no valid velocity (the frame
    # after an initialisation), retry RANSAC on descriptor-only matches against the local map
    # (ORB-SLAM's TrackReferenceKeyFrame): the window around a zero-motion prediction holds few right
    # matches when the camera moves fast (KITTI: 1.2 m per frame).
    appearance_retry: bool = False
    # ... and try the descriptor-only matches *first* (ORB-SLAM runs TrackReferenceKeyFrame whenever
    # the velocity is empty) on such a frame when its stereo gets the fill-in (stereo_fill below): the
    # fill-in's far landmarks let the window search around the zero-motion prediction (1.2 m off at
    # KITTI's speed) hand RANSAC a consensus that fixes the rotation, not the translation (frame 1 of
    # KITTI haze 0.06 + low-noise sensor 215-314 mm off; docs/notes/s13-haze.md).
    appearance_first_filled: bool = False
    # Stage 2 (ORB-SLAM TrackLocalMap): re-project the whole local map with the RANSAC pose
    # and search a small circle, then refine the pose on all those matches.
    search_radius_local: float = 4.0    # px at octave 0, scaled by the keypoint's scale
    map_max_hamming: int = 75           # KITTI uses 100 (ORB-SLAM TH_HIGH): see configs/kitti.yaml
    map_ratio: float = 0.8
    # Stage 2 applies the ratio test only when the two best keypoints sit on the same pyramid
    # level (ORB-SLAM's SearchByProjection for the local map): the same corner found again on a
    # neighbouring level is no ambiguity. False: the ratio test over all candidates.
    map_ratio_same_level: bool = True
    # Landmarks are created from stereo points closer than max_depth_baselines * baseline
    # (there is no two-view triangulation here, so far points are kept too: the stereo
    # factor's disparity noise weights them correctly in BA). "Close" points, as ORB-SLAM's
    # ThDepth, drive the keyframe condition on tracked close points.
    max_depth_baselines: float = 150.0
    # ORB-SLAM's isInFrustum for the local-map search: a landmark is searched for only when seen
    # within this angle of the ray it was created from (ORB-SLAM: 60 deg) and within its
    # descriptor's scale range; 180 switches the test off
    view_max_angle_deg: float = 180.0
    close_depth_baselines: float = 40.0
    # Stereo points farther than this are measured as monocular (bearing only) in the pose
    # refinement and in local BA: their disparity (a pixel or two) fixes no translation, and a
    # sub-pixel bias would; their stereo depth only initialises the landmark. 0: no limit.
    stereo_obs_max_depth_baselines: float = 0.0
    # Stereo points on occluding contours (trunk / crown silhouettes: the two cameras see different
    # background behind the rim, so the "corner" is a T-junction, no 3D point) are measured as
    # monocular in the pose refinement and local BA and create no landmark
    # (canopy.frontend.stereo_silhouette): a dense StereoBM disparity, on the image shrunk by
    # contour_downscale, searched to contour_max_disparity_px; a keypoint is on a contour when that
    # disparity within contour_window_px varies by more than contour_ratio (max > (1 + ratio) min) or
    # is unmatched there. Off by default: on for the generated orchard (configs/synthetic.yaml);
    # KITTI got worse with it (docs/notes/s6-drift.md).
    contour_enabled: bool = False
    contour_window_px: float = 3.0
    contour_ratio: float = 0.10
    contour_downscale: int = 2
    contour_max_disparity_px: float = 64.0
    contour_octave_scaled: bool = False  # window times scale_factor^octave (a level's SAD window)
    # Frame gate (canopy.frontend.stereo_silhouette.ContourParams): no keypoint of a frame is flagged
    # when StereoBM matched less than this fraction of it (dark / noisy enhanced frames), or when
    # more than contour_max_flagged_fraction of its stereo points would be. 0 / 1: no gate.
    contour_min_matched_fraction: float = 0.0
    contour_max_flagged_fraction: float = 1.0
    # False: only disparity steps flag a keypoint, not "no StereoBM match near it" (ContourParams)
    contour_unmatched_is_contour: bool = True
    # > 0: only unmatched regions surviving an opening of this radius (downscaled px) count (ContourParams)
    contour_unmatched_min_radius: int = 0
    # Contour points still make landmarks (placed at their stereo depth, observed bearing-only in
    # tracking and BA): without them the far crowns / sky rims that pin the heading leave the map
    # (docs/notes/s7-drift.md). False: contour points make no landmark (s6's rule).
    contour_landmarks: bool = False
    # > 0: the contour test runs only on frames whose constant-velocity motion (the last tracked
    # frame-to-frame motion) rotates by at least this many degrees, i.e. in turns. On the generated
    # day-loop the contour points fix the U-turns' pitch but make the straight rows 0.4 % long
    # (docs/notes/s11-drift.md §3, s12-drift.md). 0: every frame is tested.
    contour_min_rotation_deg: float = 0.0

    # --- motion estimation (AGRI §3.2.3: EPnP in RANSAC, then motion-only refinement)
    pnp_reprojection_error: float = 3.0  # px, RANSAC inlier threshold
    pnp_iterations: int = 100
    pnp_confidence: float = 0.999
    min_inliers: int = 15
    # When EPnP RANSAC finds no pose and the motion model is valid: refine the pose from the
    # constant-velocity prediction on the stage-1 matches it explains (ORB-SLAM's
    # TrackWithMotionModel), then the local-map search as usual; track_health still judges it.
    # On in configs/kitti.yaml (docs/notes/s7-haze.md); off here until EuRoC and the generated
    # presets are measured with it.
    track_from_prediction: bool = False
    pixel_sigma: float = 1.0            # px at octave 0 (measurement sigma = pixel_sigma * scale**octave)
    # Motion-only refinement after RANSAC (ORB-SLAM's PoseOptimization): rounds of
    # Gauss-Newton on stereo reprojection errors with a Huber kernel, re-classifying
    # outliers by chi-square after each round (95% quantiles, 2 and 3 DoF).
    pose_opt_rounds: int = 4
    pose_opt_iterations: int = 10
    chi2_mono: float = 5.991
    chi2_stereo: float = 7.815
    seed: int = 0                       # RANSAC seed; frame index is added per call

    # --- trust in a pose (canopy.frontend.track_health; issue 9) ------------------------
    # A refined pose is rejected (frame reported lost, with the reason) when fewer than
    # min_inlier_fraction of its matches agree with it, or when it departs from the
    # constant-velocity prediction by more than the deviations below (a wild pose). A rejected
    # frame within max_predicted_frames of the last tracked one gets the motion-model pose,
    # reported as "predicted" (not tracked), and the map is kept; after that tracking restarts.
    min_inlier_fraction: float = 0.2
    max_motion_deviation_m: float = 2.0
    max_motion_deviation_deg: float = 20.0
    max_predicted_frames: int = 2
    # > 0: a RANSAC pose departing from the constant-velocity prediction by more than these
    # (degrees, metres) is not taken as the start of the refinement; the prediction is, on the
    # stage-1 matches it explains (ORB-SLAM's TrackWithMotionModel), when it explains at least
    # min_inliers of them (canopy.frontend.track_health.ransac_departs). A car at 10 Hz changes its
    # per-frame motion by < 0.25 deg / 16 mm (KITTI 06 ground truth); on dark hazy frames EPnP on
    # 40-80 noisy matches picks yaw-plus-sideways poses 4-6 deg / 1 m off (docs/notes/s14-darkhaze.md).
    ransac_max_deviation_deg: float = 0.0
    ransac_max_deviation_m: float = 0.0
    # > 0: a refined pose whose camera centre lies more than this (m) from the constant-velocity
    # prediction is solved once more from the prediction (refined on the stage-1 matches it explains,
    # then the local-map search); when that lands in another minimum (centres > half this apart) with
    # more local-map inliers it replaces the first (canopy.frontend.step_check; without line features,
    # on frames after a tracked one). The small local-map window confirms a wrong start: KITTI
    # g1-b0.06-low seed 2 frame 29 ends 0.32 m short with as many inliers as its neighbours, ATE
    # 168.8 mm (seeds 0 / 1: 38.1 / 32.9); 41.0 mm with 0.2 (docs/notes/s22-stepcheck.md).
    step_max_deviation_m: float = 0.0
    # > 0: motion-only refinement adds a prior pulling the pose toward the constant-velocity
    # prediction with these standard deviations per axis (degrees / metres of the camera frame;
    # canopy.frontend.pose.MotionPrior), on frames whose motion model has seen two tracked frames.
    # Each 0 leaves its part out; both 0: off (docs/notes/s17-motionprior.md).
    motion_prior_sigma_deg: float = 0.0
    motion_prior_sigma_m: float = 0.0
    # > 0: the prior joins only refinements whose matches leave the rotation this uncertain (the
    # largest rotation std in degrees of the inverse information at the starting pose); 0: all.
    motion_prior_min_rot_std_deg: float = 0.0
    # > 0: the prior's variances per axis add this times the last pose's (diagonal of its inverse
    # information): the constant-velocity prediction 2 T_k-1 - T_k-2 carries ~5 x a pose's variance
    # when the poses' errors are independent. 0: the fixed sigmas above.
    motion_prior_pose_var_factor: float = 0.0
    # > 0: motion-only refinement adds a prior that the step from the last frame follows the rig's
    # direction of travel in the camera frame (a car's wheels do not slip sideways), learned from the
    # median of the last travel_direction_window tracked steps of >= travel_direction_min_step_m, with
    # this standard deviation across it (degrees; canopy.frontend.travel_direction). 0: off.
    travel_direction_sigma_deg: float = 0.0
    travel_direction_window: int = 20
    travel_direction_min_steps: int = 5
    travel_direction_min_step_m: float = 0.05
    # > 0: the prior joins only raw frames whose texture excess is below this (haze; 0: every frame)
    travel_direction_max_texture: float = 0.0
    # FAST threshold floor on noisy images: fast_noise_factor x the image noise sigma (Immerkaer
    # estimate); 0 switches it off. Clean images (the estimate sees fine texture too: 2-6 grey
    # levels on KITTI, EuRoC and the generated sequences) keep fast_threshold.
    fast_noise_factor: float = 3.0

    # --- keyframe selection (AGRI §3.2.4, Eq. 6-7; Kerl et al. 2013) ---------------
    entropy_ratio_alpha: float = 0.8
    min_frames_between_keyframes: int = 0
    max_frames_between_keyframes: int = 20
    min_tracked_fraction: float = 0.75  # of the reference keyframe's tracked landmarks
    min_new_close_points: int = 70      # ORB-SLAM stereo: insert when few close points tracked
    min_tracked_close: int = 100
    min_init_points: int = 100          # stereo points needed to (re)start a map
    # Relocalisation (issue 10): after tracking is lost, the next frames are tracked against
    # the same local map from the constant-velocity prediction carried over the lost frames
    # (and appearance matching when it is off); only after this many lost frames does
    # tracking start a new map at the last good pose. 0: start a new map at once.
    relocalise_bridge_frames: int = 10

    # --- line features in tracking (AGRI §3.2.1-3.2.3, Eq. 10-11; issue 4) -----------
    # Off: the points-only pipeline runs unchanged. On: FLD/LSD segments of the left image
    # are detected and LBD-described in a worker thread (queued behind the right image's ORB);
    # the right image's lines are needed only at keyframes (stereo lines create map lines
    # there): queued in the same worker when a keyframe is likely, else computed on demand.
    use_lines: bool = False
    line_detector: str = "fld"
    line_max_lines: int = 100           # longest segments kept per image (LBD cost ~ count)
    line_min_length_fraction: float = 0.03  # of the image diagonal (27 px at 752x480)
    # Lines are detected and LBD-described on the image resized by this factor (FLD + LBD cost
    # ~ pixels; at 0.5 they cost ~6 ms instead of ~15 ms at 752x480); endpoints are mapped back.
    line_image_scale: float = 0.5
    line_search_radius: float = 15.0    # px: observed endpoints to the projected map line
    line_search_radius_wide: float = 40.0  # px, when the pose comes from the prediction only
    line_max_angle_deg: float = 10.0    # directed angle, projected map line vs segment
    line_max_hamming: int = 80          # LBD, of 256 bits
    line_ratio: float = 0.85            # best / second-best Hamming distance
    line_sigma: float = 1.0             # px, sigma of each endpoint-to-line distance (Eq. 11)
    chi2_line: float = 5.991            # 95% of chi2(2): both endpoint distances of one line
    line_max_depth_baselines: float = 60.0  # new map lines: both endpoints closer than this
    line_weight_in_count: int = 1       # a line inlier counts as this many point inliers

    # --- noisy sensor (issue 9; canopy.frontend.noisy_features.refinement_pair) ---------------
    # Sub-pixel stereo refinement (the SAD parabola) on a smoothed copy of the pair when the left
    # image's robust noise sigma (canopy.enhance.noise.estimate_noise, grey levels) is at least
    # subpixel_denoise_sigma: the keypoints and descriptor matches stay those of the raw frame,
    # only u_right (the depth) is measured on the smoothed pair. 0: off. subpixel_denoise_blur:
    # the Gaussian's sigma in px (level-0 pixels); 0 = the guided self-filter of canopy.enhance.noise.
    subpixel_denoise_sigma: float = 0.0
    subpixel_denoise_blur: float = 2.0  # the best sum over KITTI's 4 noisy cells (two noise draws)
    # subpixel_raw_vertex_search > 0: the smoothed pair's SAD picks only the whole-pixel minimum, and the
    # raw pair's SAD over +-subpixel_raw_vertex_search px around it gives the sub-pixel vertex (0: the
    # smoothed pair's vertex). The Gaussian's vertex is biased by depth band on KITTI's clean frames
    # (far points +0.15 px, 8-20 px -0.065 px at blur 2, where 0.05 px moves the scale 0.2 %); the raw
    # vertex around the smoothed minimum is not (docs/notes/s31-vertex.md). On by default: it acts only where
    # subpixel_denoise_sigma smooths a frame (off by default; configs/kitti.yaml turns both on)
    subpixel_raw_vertex_search: int = 2
    # Extractor by image noise (canopy.frontend.noisy_features.NoiseGatedExtractor), with
    # extractor: opencv: an image whose noise sigma (track_health.image_noise_sigma) is at least
    # noisy_extractor_sigma gets ORB-SLAM's per-cell extraction (the cells settings above, its
    # fallback at cell_fallback_noise_factor x sigma) with noisy_extractor_n_features corners (0:
    # n_features); other images keep cv2.ORB. 0: off.
    noisy_extractor_sigma: float = 0.0
    noisy_extractor_n_features: int = 0
    # With extractor: cells (canopy.frontend.noisy_features.NoiseGatedCellFallback): an image whose
    # robust noise sigma (canopy.enhance.noise.estimate_noise, the refinement's estimator above) is at
    # least cell_fallback_noisy_sigma gets the per-cell fallback at cell_fallback_noise_factor_noisy x
    # sigma; other images keep cell_fallback_noise_factor. 0: off (every image the same factor).
    # cell_fallback_noisy_min_texture: ... and only if the image has texture above its noise:
    # track_health.image_noise_sigma (mean |Laplacian|, texture + noise) minus the robust sigma
    # (median, noise) at least this many grey levels (haze flattens the texture). 0: no texture test.
    cell_fallback_noisy_sigma: float = 0.0
    cell_fallback_noise_factor_noisy: float = 4.0
    cell_fallback_noisy_min_texture: float = 0.0
    # NoiseGatedExtractor judged by the robust sigma (the generated presets, docs/notes/s12-presets.md):
    # noisy_extractor_robust: the gate compares the robust sigma (estimate_noise, rows_fraction 0.5)
    # with noisy_extractor_sigma instead of the mean one, which fine texture raises (clean day-loop
    # 4.6-8.9 mean, 2.1-3.1 robust). noisy_extractor_max_texture: ... and only images whose texture
    # excess (mean - robust sigma) is below this many grey levels: noisy *and* flat (haze, a washed-out
    # row) get the per-cell extractor; noisy, textured ones keep cv2.ORB. 0: no texture test.
    noisy_extractor_robust: bool = False
    noisy_extractor_max_texture: float = 0.0
    # s17-darkrows: NoiseGatedExtractor's per-cell extraction with each coarser pyramid level's FAST
    # thresholds from that level's own noise sigma (canopy.frontend.level_noise_extractor). False: off.
    noisy_extractor_level_noise: bool = False
    # s24-lead: ... only on images whose texture excess (mean - robust sigma, the gate above) is below this
    # many grey levels: the scene's texture is under the noise at full resolution and shows only on coarser
    # levels (docs/notes/s24-lead.md). 0: no test (every per-cell image, s17's switch as it was).
    noisy_extractor_level_noise_max_texture: float = 0.0
    # Stereo fill-in (canopy.frontend.stereo_fill): the left keypoints the descriptor matcher leaves
    # unmatched get a right column by LK flow (the right image's FAST misses half the far,
    # low-contrast corners of a hazy frame) on frames whose robust noise sigma is in
    # [stereo_fill_min_sigma, stereo_fill_max_sigma) (max 0: no upper bound) and, with
    # stereo_fill_max_texture > 0, whose texture excess (mean - robust sigma: haze flattens it) is
    # below that. False: off (docs/notes/s13-haze.md).
    stereo_fill: bool = False
    stereo_fill_min_sigma: float = 0.0
    stereo_fill_max_sigma: float = 0.0
    stereo_fill_max_texture: float = 0.0  # ... and texture excess (mean - robust sigma) below this (0: no test)
    # s20-dimsigma: frames the enhancement changed carry no robust sigma (the extractor measures it on raw
    # frames only); with stereo_fill_enhanced_min_sensor_sigma > 0 they get the fill-in when the enhancement's
    # own noise sigma of the frame (the lifted image's, before its denoiser; handed over with the frame) is in
    # [min, max) (max 0: no upper bound). 0: off (docs/notes/s20-dimsigma.md; s19's gate on the enhanced
    # image's robust sigma and texture, docs/notes/s19-dimfill.md, is gone: it measured texture more than noise).
    stereo_fill_enhanced_min_sensor_sigma: float = 0.0
    stereo_fill_enhanced_max_sensor_sigma: float = 0.0
    # s21-hazedepth: zero-mean SAD (subpixel_normalise "mean") on the frames the fill-in gate opens on (canopy.frontend.stereo)
    subpixel_mean_on_fill: bool = False
    # s24-kittinoisy: zero-mean SAD also on hazy frames of the noisy sensor, whose pair the refinement smooths
    # (robust sigma >= subpixel_denoise_sigma) and whose texture excess is below stereo_fill_max_texture (> 0
    # needed: noise alone keeps its texture); the fill-in's gate is shut there (stereo_fill_max_sigma)
    # (canopy.frontend.stereo_fill.mean_on_noisy_haze). False: off; on in configs/kitti.yaml (docs/notes/s24-kittinoisy.md).
    subpixel_mean_on_noisy_haze: bool = False
    # Stereo points whose disparity the image cannot pin (canopy.frontend.keypoint_uncertainty; issue 9's
    # haze + noisy sensor): on frames whose robust noise sigma is >= uncertain_stereo_min_noise, a stereo
    # point whose Cramer-Rao disparity sigma (the 11x11 SAD window's x-gradients against the noise) is at
    # least uncertain_stereo_max_rel_sigma x its disparity (= its relative depth sigma) makes no landmark
    # (uncertain_stereo_landmarks false) and/or is measured bearing-only in pose refinement and BA
    # (uncertain_stereo_bearing_only, ORB-SLAM's ThDepth role; measured worse). 0: off
    # (docs/notes/s16-darkhaze.md).
    uncertain_stereo_max_rel_sigma: float = 0.0
    uncertain_stereo_min_noise: float = 4.0
    uncertain_stereo_bearing_only: bool = False
    uncertain_stereo_landmarks: bool = False
    # ... the bound with the noise as the octave's resampled window carries it (4/9 of white at octaves
    # >= 1; keypoint_uncertainty.sampled_noise_factors, docs/notes/s17-kittihaze.md). False: white.
    uncertain_stereo_sampled_noise: bool = False
    # s30-offset: on frames whose robust noise sigma is >= uncertain_stereo_min_noise, stereo points beyond
    # this many baselines are bearing-only in pose refinement and BA (ORB-SLAM's ThDepth, 40, on noisy
    # frames only); their depth still initialises landmarks. With the map-calibrated KITTI offset the noisy
    # sensor's path came out 0.16-0.22 % long while clean frames' was right; far stereo depths bearing-only
    # brought it to 0.05-0.07 % on two draws, but over seven draws of the noisy lit cell it is bimodal
    # (20-24 mm on five, 56 / 82 on two) and the hazy one is worse (57.5 -> 63.0 mm mean), so it is off
    # everywhere (docs/notes/s30-offset.md). 0: off.
    noisy_stereo_obs_max_depth_baselines: float = 0.0
    # s25-attitude: each keyframe's up measured from its vertical segments (canopy.lines.vertical, through
    # canopy.frontend.tracker_vertical) rides on the KeyframeData for mapping.attitude_prior; estimates whose
    # sigma is above vertical_max_sigma_deg are not sent. False: no measurement (docs/notes/s25-attitude.md).
    vertical_estimate: bool = False
    vertical_max_sigma_deg: float = 2.0
    # ... and every tracked frame's up (the same estimator, gated by the predicted pose; ~2.5 ms a frame) as a
    # prior on its pitch and roll in the motion-only refinement, against the reference of the map segment's
    # first measured keyframe (canopy.frontend.tracker_vertical). False: off.
    vertical_track_prior: bool = False
    # the estimator's sigma times this, in the keyframes' up_sigma_deg and the frames' term (1: as measured)
    vertical_sigma_scale: float = 1.0
    # s26-gate: a keyframe sends its up only where its far pose inliers (beyond vertical_gate_far_baselines;
    # 40: ORB-SLAM's ThDepth) hold its pitch/roll weakly: their own pitch/roll sigma >= vertical_gate_ratio x
    # the up's sigma (canopy.frontend.vertical_gate; docs/notes/s26-gate.md). 0: no gate (always sent).
    vertical_gate_ratio: float = 0.0
    vertical_gate_far_baselines: float = 40.0
    # ... on this keyframe and the vertical_gate_keyframes - 1 before it (the haze is a stretch, not a frame)
    vertical_gate_keyframes: int = 1
    # > 0: ... and only keyframes whose frame the enhancement denoised at a noise sigma of at least this (the
    # enhancement's own figure, as stereo_fill_enhanced_min_sensor_sigma reads it: the dim noisy cells 14.6-16.1,
    # every clean preset frame <= 9.21; raw frames 0). 0: every keyframe.
    vertical_min_sensor_sigma: float = 0.0

    def disparity_offset_for(self, extractor: str) -> float:
        """The calibrated disparity offset for keypoints found by ``extractor`` (Features.extractor)."""
        return self.disparity_offset_cells_px if extractor == "cells" else self.disparity_offset_px

    def validate(self) -> "TrackingParams":
        """Range-check every field (canopy.frontend.params_checks); raise ConfigError naming the field."""
        return validate_tracking_params(self)

    def __post_init__(self):
        self.validate()
