"""Range checks of ``TrackingParams`` (canopy.frontend.params), kept apart from the fields.

The dataclass holds each field with its rationale; this module says which values are valid, so that a
wrong configuration fails at load time with the field's name (shared.errors.ConfigError).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from shared.errors import ConfigError

EXTRACTORS = ("opencv", "cells")  # TrackingParams.extractor / extractor_enhanced

if TYPE_CHECKING:
    from canopy.frontend.params import TrackingParams


def validate_tracking_params(p: "TrackingParams") -> "TrackingParams":
    """Raise ConfigError naming the first out-of-range field of ``p``; return ``p``."""
    def need(ok: bool, name: str, what: str) -> None:
        if not ok:
            raise ConfigError("TrackingParams", f"{name} {what} (got {getattr(p, name)!r})")

    need(p.n_features > 0, "n_features", "must be > 0")
    need(p.opencv_threads >= 0, "opencv_threads", "must be >= 0 (0: OpenCV's default)")
    need(0 <= p.switch_interval_ms <= 100, "switch_interval_ms", "must be in [0, 100] (0: Python's default)")
    need(p.scale_factor > 1.0, "scale_factor", "must be > 1")
    need(1 <= p.n_levels <= 16, "n_levels", "must be in [1, 16]")
    need(0 < p.fast_threshold < 255, "fast_threshold", "must be in (0, 255)")
    need(p.extractor in EXTRACTORS, "extractor", f"must be one of {EXTRACTORS}")
    need(p.extractor_enhanced in EXTRACTORS, "extractor_enhanced", f"must be one of {EXTRACTORS}")
    need(p.enhanced_cells_min_corners >= 0, "enhanced_cells_min_corners", "must be >= 0 (0: off)")
    need(p.enhanced_cells_noise_factor >= 0, "enhanced_cells_noise_factor", "must be >= 0")
    need(0 < p.enhanced_cells_corner_weight <= 1, "enhanced_cells_corner_weight", "must be in (0, 1]")
    need(p.cell_size >= 8, "cell_size", "must be >= 8 px")
    need(p.cell_ranking in ("harris2x", "fast", "harris"), "cell_ranking", "must be harris2x, fast or harris")
    need(0 < p.fast_fallback_threshold < 255, "fast_fallback_threshold", "must be in (0, 255)")
    need(p.cell_fallback_noise_factor >= 0, "cell_fallback_noise_factor", "must be >= 0")
    need(p.cell_fallback_noisy_sigma >= 0, "cell_fallback_noisy_sigma", "must be >= 0 (0: off)")
    need(p.cell_fallback_noise_factor_noisy >= 0, "cell_fallback_noise_factor_noisy", "must be >= 0")
    need(p.cell_fallback_noisy_min_texture >= 0, "cell_fallback_noisy_min_texture", "must be >= 0 (0: no test)")
    need(p.stereo_fill_min_sigma >= 0, "stereo_fill_min_sigma", "must be >= 0")
    need(p.stereo_fill_max_sigma >= 0, "stereo_fill_max_sigma", "must be >= 0 (0: no upper bound)")
    need(p.stereo_fill_max_texture >= 0, "stereo_fill_max_texture", "must be >= 0 (0: no test)")
    need(p.stereo_fill_enhanced_min_sensor_sigma >= 0, "stereo_fill_enhanced_min_sensor_sigma", "must be >= 0 (0: off)")
    need(p.stereo_fill_enhanced_max_sensor_sigma >= 0, "stereo_fill_enhanced_max_sensor_sigma",
         "must be >= 0 (0: no upper bound)")
    need(p.noisy_extractor_max_texture >= 0, "noisy_extractor_max_texture", "must be >= 0 (0: no test)")
    need(p.noisy_extractor_max_texture == 0 or p.noisy_extractor_robust, "noisy_extractor_max_texture",
         "needs noisy_extractor_robust: true (the excess is mean - robust sigma)")
    need(p.noisy_extractor_level_noise_max_texture >= 0, "noisy_extractor_level_noise_max_texture",
         "must be >= 0 (0: no test)")
    need(p.noisy_extractor_level_noise_max_texture == 0
         or (p.noisy_extractor_level_noise and p.noisy_extractor_robust), "noisy_extractor_level_noise_max_texture",
         "needs noisy_extractor_level_noise: true and noisy_extractor_robust: true")
    need(p.grid_cols > 0 and p.grid_rows > 0, "grid_cols", "and grid_rows must be > 0")
    need(p.oversample >= 1.0, "oversample", "must be >= 1")
    need(0 <= p.stereo_max_hamming <= 256, "stereo_max_hamming", "must be in [0, 256]")
    need(0 < p.stereo_ratio <= 1, "stereo_ratio", "must be in (0, 1]")
    need(p.stereo_matcher in ("descriptor", "flow"), "stereo_matcher", "must be 'descriptor' or 'flow'")
    need(p.flow_window >= 3 and p.flow_window % 2 == 1, "flow_window", "must be odd and >= 3")
    need(0 <= p.flow_levels <= 8, "flow_levels", "must be in [0, 8]")
    need(p.flow_iterations >= 1, "flow_iterations", "must be >= 1")
    need(p.flow_min_eig > 0, "flow_min_eig", "must be > 0")
    need(p.flow_max_dy > 0, "flow_max_dy", "must be > 0")
    need(p.flow_back_px >= 0, "flow_back_px", "must be >= 0 (0: no back-track)")
    need(0 <= p.flow_back_levels <= 8, "flow_back_levels", "must be in [0, 8]")
    need(p.min_disparity > 0, "min_disparity", "must be > 0")
    need(0 < p.max_disparity_fraction <= 1, "max_disparity_fraction", "must be in (0, 1]")
    need(p.row_tolerance >= 0, "row_tolerance", "must be >= 0")
    need(p.subpixel_window >= 1, "subpixel_window", "must be >= 1")
    need(p.sad_outlier_factor_noisy > 0, "sad_outlier_factor_noisy",
         "must be > 0 (at or above sad_outlier_factor: off)")
    need(0 <= p.sad_snr_low < p.sad_snr_high, "sad_snr_low", "must be >= 0 and < sad_snr_high")
    need(p.subpixel_search >= 1, "subpixel_search", "must be >= 1")
    need(p.subpixel_normalise in ("centre", "mean"), "subpixel_normalise", "must be 'centre' or 'mean'")
    need(p.subpixel_denoise_sigma >= 0, "subpixel_denoise_sigma", "must be >= 0 (0: off)")
    need(p.subpixel_denoise_blur >= 0, "subpixel_denoise_blur", "must be >= 0 (0: guided filter)")
    need(0 <= p.subpixel_raw_vertex_search <= p.subpixel_search, "subpixel_raw_vertex_search",
         "must be in [0, subpixel_search] (0: off)")
    need(not p.subpixel_mean_on_noisy_haze or (p.subpixel_denoise_sigma > 0 and p.stereo_fill_max_texture > 0),
         "subpixel_mean_on_noisy_haze", "needs subpixel_denoise_sigma > 0 and stereo_fill_max_texture > 0 "
         "(the noisy gate and the haze test)")
    need(abs(p.disparity_offset_px) < 5, "disparity_offset_px", "must be within +-5 px")
    need(abs(p.disparity_offset_cells_px) < 5, "disparity_offset_cells_px", "must be within +-5 px")
    need(p.search_radius > 0, "search_radius", "must be > 0")
    need(p.search_radius_wide >= p.search_radius, "search_radius_wide", "must be >= search_radius")
    need(p.search_radius_local > 0, "search_radius_local", "must be > 0")
    need(0 < p.map_ratio <= 1, "map_ratio", "must be in (0, 1]")
    need(p.max_depth_baselines > 0, "max_depth_baselines", "must be > 0")
    need(p.close_depth_baselines > 0, "close_depth_baselines", "must be > 0")
    need(p.stereo_obs_max_depth_baselines >= 0, "stereo_obs_max_depth_baselines", "must be >= 0 (0: no limit)")
    need(p.contour_window_px >= 1, "contour_window_px", "must be >= 1 px")
    need(p.contour_ratio > 0, "contour_ratio", "must be > 0")
    need(p.contour_downscale in (1, 2, 4), "contour_downscale", "must be 1, 2 or 4")
    need(p.contour_max_disparity_px > 0, "contour_max_disparity_px", "must be > 0")
    need(0.0 <= p.contour_min_matched_fraction <= 1.0, "contour_min_matched_fraction", "must be in [0, 1]")
    need(p.contour_unmatched_min_radius >= 0, "contour_unmatched_min_radius", "must be >= 0")
    need(0.0 < p.contour_max_flagged_fraction <= 1.0, "contour_max_flagged_fraction", "must be in (0, 1]")
    need(p.contour_min_rotation_deg >= 0, "contour_min_rotation_deg", "must be >= 0 degrees")
    need(p.pnp_reprojection_error > 0, "pnp_reprojection_error", "must be > 0")
    need(p.pnp_iterations > 0, "pnp_iterations", "must be > 0")
    need(0 < p.pnp_confidence < 1, "pnp_confidence", "must be in (0, 1)")
    need(p.min_inliers >= 6, "min_inliers", "must be >= 6 (a pose has 6 DoF)")
    need(0 <= p.min_inlier_fraction < 1, "min_inlier_fraction", "must be in [0, 1)")
    need(p.max_motion_deviation_m > 0, "max_motion_deviation_m", "must be > 0")
    need(p.max_motion_deviation_deg > 0, "max_motion_deviation_deg", "must be > 0")
    need(p.ransac_max_deviation_deg >= 0, "ransac_max_deviation_deg", "must be >= 0 (0: off)")
    need(p.ransac_max_deviation_m >= 0, "ransac_max_deviation_m", "must be >= 0 (0: off)")
    need(p.step_max_deviation_m >= 0, "step_max_deviation_m", "must be >= 0 (0: off)")
    need(p.motion_prior_sigma_deg >= 0, "motion_prior_sigma_deg", "must be >= 0 (0: off)")
    need(p.motion_prior_sigma_m >= 0, "motion_prior_sigma_m", "must be >= 0 (0: off)")
    need(p.motion_prior_min_rot_std_deg >= 0, "motion_prior_min_rot_std_deg", "must be >= 0 (0: always)")
    need(p.motion_prior_pose_var_factor >= 0, "motion_prior_pose_var_factor", "must be >= 0 (0: off)")
    need(p.vertical_min_sensor_sigma >= 0, "vertical_min_sensor_sigma", "must be >= 0 (0: every keyframe)")
    need(p.travel_direction_sigma_deg >= 0, "travel_direction_sigma_deg", "must be >= 0 (0: off)")
    need(p.travel_direction_window >= 1, "travel_direction_window", "must be >= 1")
    need(1 <= p.travel_direction_min_steps <= p.travel_direction_window, "travel_direction_min_steps",
         "must be in [1, travel_direction_window]")
    need(p.travel_direction_min_step_m > 0, "travel_direction_min_step_m", "must be > 0")
    need(p.travel_direction_max_texture >= 0, "travel_direction_max_texture", "must be >= 0 (0: every frame)")
    need(p.max_predicted_frames >= 0, "max_predicted_frames", "must be >= 0")
    need(p.fast_noise_factor >= 0, "fast_noise_factor", "must be >= 0")
    need(p.pixel_sigma > 0, "pixel_sigma", "must be > 0")
    need(p.pose_opt_rounds >= 1, "pose_opt_rounds", "must be >= 1")
    need(p.pose_opt_iterations >= 1, "pose_opt_iterations", "must be >= 1")
    need(p.chi2_mono > 0 and p.chi2_stereo > 0, "chi2_mono", "and chi2_stereo must be > 0")
    need(0 < p.entropy_ratio_alpha < 1, "entropy_ratio_alpha", "must be in (0, 1)")
    need(p.min_frames_between_keyframes >= 0, "min_frames_between_keyframes", "must be >= 0")
    need(p.max_frames_between_keyframes > p.min_frames_between_keyframes,
         "max_frames_between_keyframes", "must exceed min_frames_between_keyframes")
    need(0 < p.min_tracked_fraction <= 1, "min_tracked_fraction", "must be in (0, 1]")
    need(p.relocalise_bridge_frames >= 0, "relocalise_bridge_frames", "must be >= 0")
    need(p.min_init_points >= p.min_inliers, "min_init_points", "must be >= min_inliers")
    need(p.line_detector in ("fld", "lsd"), "line_detector", "must be 'fld' or 'lsd'")
    need(p.line_max_lines > 0, "line_max_lines", "must be > 0")
    need(0.25 <= p.line_image_scale <= 1.0, "line_image_scale", "must be in [0.25, 1]")
    need(0 < p.line_min_length_fraction < 1, "line_min_length_fraction", "must be in (0, 1)")
    need(0 < p.line_search_radius <= p.line_search_radius_wide, "line_search_radius",
         "must be in (0, line_search_radius_wide]")
    need(0 < p.line_max_angle_deg < 90, "line_max_angle_deg", "must be in (0, 90)")
    need(0 <= p.line_max_hamming <= 256, "line_max_hamming", "must be in [0, 256]")
    need(0 < p.line_ratio <= 1, "line_ratio", "must be in (0, 1]")
    need(p.line_sigma > 0 and p.chi2_line > 0, "line_sigma", "and chi2_line must be > 0")
    need(p.line_max_depth_baselines > 0, "line_max_depth_baselines", "must be > 0")
    need(p.line_weight_in_count >= 0, "line_weight_in_count", "must be >= 0")
    need(p.noisy_extractor_sigma >= 0, "noisy_extractor_sigma", "must be >= 0 (0: off)")
    need(p.noisy_extractor_n_features >= 0, "noisy_extractor_n_features", "must be >= 0 (0: n_features)")
    need(p.uncertain_stereo_max_rel_sigma >= 0, "uncertain_stereo_max_rel_sigma", "must be >= 0 (0: off)")
    need(p.uncertain_stereo_min_noise >= 0, "uncertain_stereo_min_noise", "must be >= 0")
    need(p.noisy_stereo_obs_max_depth_baselines >= 0, "noisy_stereo_obs_max_depth_baselines", "must be >= 0 (0: off)")
    need(p.vertical_max_sigma_deg > 0, "vertical_max_sigma_deg", "must be > 0")
    need(p.vertical_sigma_scale > 0, "vertical_sigma_scale", "must be > 0")
    need(p.vertical_gate_ratio >= 0, "vertical_gate_ratio", "must be >= 0 (0: no gate)")
    need(p.vertical_gate_far_baselines >= 0, "vertical_gate_far_baselines", "must be >= 0")
    need(p.vertical_gate_keyframes >= 1, "vertical_gate_keyframes", "must be >= 1")
    need(p.vertical_estimate or not p.vertical_track_prior, "vertical_track_prior",
         "needs vertical_estimate (the keyframes' measurements set the reference)")
    return p
