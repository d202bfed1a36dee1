"""Which extractor a frame the enhancement changed goes to, on a ``cells`` tracker with
``extractor_enhanced: opencv`` (KITTI): cv2.ORB with AFE's thresholds (``OrbExtractor``), or
ORB-SLAM's per-cell extractor (``CellExtractor``) with AFE's Eq. 18 threshold per cell and a
fallback floor of ``enhanced_cells_noise_factor`` x the enhanced image's noise sigma.

The rule (docs/notes/s12-dark.md): the per-cell extractor when AFE's Eq. 18 threshold θ finds at
least ``enhanced_cells_min_corners`` FAST corners in the enhanced image, i.e. the image has
contrast above θ somewhere; cv2.ORB (in effect its Eq. 19 retry at a few grey levels, ranked by
Harris response over the whole image) when Eq. 18 finds (almost) none. Why: the per-cell
extractor fills every cell, so on an image with no corner above θ every cell's corners come from
the low fallback threshold, and in the flat cells of a strongly denoised dark frame those are
residues of the noise that do not match in the right image (KITTI 2 % light, noisy sensor: 216 ->
104 stereo points at initialisation, 74.5 -> 7.8 % tracked); cv2.ORB's global Harris ranking keeps
the few real corners. Where θ finds corners the per-cell spread pays (15 % light, noisy sensor
56.5 -> 26 mm). The 4 sigma floor (s11-noise's rule for noisy raw images) keeps the fallback
corners of the enhanced image above what its remaining noise can flip (15 % light, low-noise
sensor: 63.6 mm with the 2 sigma floor, 44.9 with 4 sigma; cv2.ORB 39.4).

The count is smoothed over the sequence (an exponential moving average, the newest image weighing
``enhanced_cells_corner_weight``): a hazy noisy sequence whose frames find 0-17 corners would
otherwise switch extractor from frame to frame, and the switching lost frames (KITTI 15 % light,
haze 0.06, noisy sensor, second noise draw: 100 -> 74.5 % tracked with a per-frame decision).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.frontend.params import TrackingParams
from canopy.frontend.track_health import image_noise_sigma


class EnhancedCellsRule:
    """``fallback(image, fast_threshold, fallback_threshold, noise_sigma)``: the per-cell fallback
    threshold for an enhanced ``image`` (AFE's thresholds given), or None when it goes to cv2.ORB
    (always with ``enhanced_cells_min_corners`` 0). One instance per image stream (it keeps the
    smoothed corner count of the enhanced images it has seen)."""

    def __init__(self, params: TrackingParams):
        self.params = params
        self._fast = cv2.FastFeatureDetector_create(int(params.fast_threshold), True,
                                                    cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
        self.last_corners: int | None = None
        self.smoothed_corners: float | None = None

    def fallback(self, image: np.ndarray, fast_threshold: int | None, fallback_threshold: int,
                 noise_sigma: float | None = None) -> int | None:
        """``noise_sigma``: the image's ``image_noise_sigma`` if the caller measured it."""
        self.last_corners = None
        need = int(self.params.enhanced_cells_min_corners)
        if need <= 0:
            return None
        theta = int(self.params.fast_threshold if fast_threshold is None else fast_threshold)
        self._fast.setThreshold(min(max(theta, 1), 254))
        self.last_corners = n = len(self._fast.detect(image))
        w = float(self.params.enhanced_cells_corner_weight)
        m = self.smoothed_corners
        self.smoothed_corners = m = float(n) if m is None else (1.0 - w) * m + w * n
        if m < need:
            return None
        sigma = image_noise_sigma(image) if noise_sigma is None else float(noise_sigma)
        floor = int(np.ceil(self.params.enhanced_cells_noise_factor * sigma))
        return int(min(max(int(fallback_threshold), floor), 254))
