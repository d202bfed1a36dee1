"""The per-cell extractor with a FAST floor measured on each pyramid level (issue 9, the generated
presets' haze + noisy-sensor cells; docs/notes/s17-darkrows.md).

``CellExtractor`` takes one noise sigma, measured on the full-resolution image, and puts both FAST
thresholds at or above multiples of it (``fast_noise_factor`` x sigma for the first pass,
``cell_fallback_noise_factor`` x sigma for the per-cell fallback) on every level. But each level is
the previous one resized by 1/1.2 with bilinear interpolation, which averages neighbouring pixels: the
noise falls level by level (the grid's dark-rows g1-b0.06-high frame 0, ``image_noise_sigma``: 5.3,
3.7, 2.8, 2.3, 2.0 on levels 0-4; the median estimate ``estimate_noise``: 4.9, 2.6, 1.5, 1.0, 0.8),
while a blotch of ground texture a few pixels wide keeps its contrast. With one sigma, the fallback
floor (4 x 5.3 = 22 grey levels) is above what the hazy ground's texture reaches on any level, and
every keypoint of that frame sits on a crown silhouette against the haze (99 % of the tracker's
inliers; their image positions slide along the contour as the camera moves, so they are not fixed
3D points). ``LevelNoiseCellExtractor`` measures the sigma of each coarser level and lowers that
level's thresholds to the same multiples of it (never below ``fast_threshold`` /
``fast_fallback_threshold``, never above the full-resolution ones): corners still stand the same
number of sigmas above the noise of the image they are detected on.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.track_health import image_noise_sigma


def level_thresholds(high: int, low: int, level_sigma: float, fast_threshold: int, fast_fallback_threshold: int,
                     fast_noise_factor: float, fallback_noise_factor: float) -> tuple[int, int]:
    """(first-pass, fallback) FAST thresholds of a coarser pyramid level whose noise sigma is
    ``level_sigma``: the noise multiples of that sigma, floored at the configured thresholds and capped
    at the full-resolution level's ``high`` / ``low``."""
    high_l = max(int(fast_threshold), int(np.ceil(fast_noise_factor * level_sigma)))
    low_l = max(int(fast_fallback_threshold), int(np.ceil(fallback_noise_factor * level_sigma)))
    return min(int(high), high_l), min(int(low), low_l)


class LevelNoiseCellExtractor(CellExtractor):
    """``CellExtractor`` whose pyramid levels above 0 get FAST thresholds from their own noise sigma
    (``track_health.image_noise_sigma`` of the level; see the module docstring). Level 0 is
    ``CellExtractor``'s to the pixel."""

    def __init__(self, params, responses: bool = True):
        super().__init__(params, responses)
        self._full_shape: tuple[int, int] | None = None
        self.last_level_thresholds: list[tuple[int, int]] = []

    def extract(self, image, fast_threshold=None, fallback_threshold=None, min_keypoints=0, noise_sigma=None):
        self._full_shape = None if image is None else np.asarray(image).shape
        self.last_level_thresholds = []
        return super().extract(image, fast_threshold, fallback_threshold, min_keypoints, noise_sigma=noise_sigma)

    def detect_level(self, img: np.ndarray, high: int, low: int):
        if self._full_shape is not None and img.shape != self._full_shape:
            p = self.params
            high, low = level_thresholds(high, low, image_noise_sigma(img), p.fast_threshold,
                                         p.fast_fallback_threshold, p.fast_noise_factor, p.cell_fallback_noise_factor)
        self.last_level_thresholds.append((int(high), int(low)))
        return super().detect_level(img, high, low)
