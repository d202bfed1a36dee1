"""Image enhancement before feature extraction (AGRI-SLAM §3.1, AFE-ORB-SLAM §4).

Pure functions on uint8 grey (H, W) or BGR (H, W, 3) images; each returns a
uint8 image of the same shape. Choose one by name with ``make_enhancer``.
"""
from canopy.enhance.agcwd import agcwd_curve, agcwd_unsharp, intensity_lambda
from canopy.enhance.auto import apply_decision, auto, auto_decide, auto_full, auto_statistics, auto_treat
from canopy.enhance.baselines import clahe, histogram_equalise, none
from canopy.enhance.common import check_image
from canopy.enhance.dehaze import atmospheric_light, dark_channel, dehaze_dark_channel, dehaze_inverted
from canopy.enhance.factory import METHOD_FUNCTIONS, make_enhancer, pair_arguments
from canopy.enhance.fast import (FAST_THRESHOLD_RANGE, adaptive_fast_threshold, detect_orb_adaptive,
                                 fallback_fast_threshold, tracking_fast_arguments)
from canopy.enhance.noise import denoise, estimate_noise, guided_self_filter
from canopy.enhance.params import AUTO_DECISIONS, ENHANCE_METHODS, EnhanceParams

__all__ = [
    "AUTO_DECISIONS", "ENHANCE_METHODS", "EnhanceParams", "FAST_THRESHOLD_RANGE", "METHOD_FUNCTIONS",
    "adaptive_fast_threshold", "agcwd_curve", "agcwd_unsharp", "apply_decision", "atmospheric_light", "auto",
    "auto_decide", "auto_full", "auto_statistics", "denoise", "estimate_noise", "guided_self_filter", "check_image", "clahe", "dark_channel", "dehaze_dark_channel",
    "dehaze_inverted", "detect_orb_adaptive", "fallback_fast_threshold", "histogram_equalise",
    "intensity_lambda", "make_enhancer", "none", "pair_arguments", "auto_treat", "tracking_fast_arguments",
]
