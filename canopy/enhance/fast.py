"""AFE-ORB-SLAM §4.2: adaptive FAST threshold for ORB extraction (Eq. 18–19).

λ is the same quantity the enhancement uses (AFE: "the λ used for the image
enhancement is utilised to control the value of θ"): the grey-level standard
deviation on a [0, 1] scale. With ω = 128, θ = 128 λ + 20 (Eq. 18) is the
first try — for EuRoC (λ ≈ 0.21) θ ≈ 47 — and θ = 128 λ / 2 (Eq. 19) the retry
when too few keypoints result, mirroring ORB-SLAM3's iniThFAST 20 / minThFAST 7.
Thresholds are rounded and clamped to [1, 255] (FAST compares 8-bit
differences; θ = 0 would make every pixel a corner candidate).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.enhance.agcwd import intensity_lambda
from canopy.enhance.common import check_image
from canopy.enhance.params import EnhanceParams

FAST_THRESHOLD_RANGE = (1, 255)


def _clamp(theta: float) -> int:
    lo, hi = FAST_THRESHOLD_RANGE
    return int(min(hi, max(lo, round(theta))))


def adaptive_fast_threshold(image: np.ndarray, omega: float = 128.0) -> int:
    """θ = ω·λ + 20 (Eq. 18), clamped to [1, 255]."""
    return _clamp(omega * intensity_lambda(image) + 20.0)


def fallback_fast_threshold(image: np.ndarray, omega: float = 128.0) -> int:
    """θ = ω·λ / 2 (Eq. 19), for frames where Eq. 18 gives too few keypoints; clamped to [1, 255]."""
    return _clamp(omega * intensity_lambda(image) / 2.0)


def detect_orb_adaptive(image: np.ndarray, orb, params: EnhanceParams | None = None,
                        min_keypoints: int | None = None, mask: np.ndarray | None = None):
    """ORB detect+compute with AFE's adaptive FAST threshold.

    Sets ``orb.setFastThreshold(θ)`` with Eq. 18's θ and, if fewer than
    ``min_keypoints`` (default ``params.min_keypoints``) result, retries with
    Eq. 19's θ. With ``params.adaptive_fast`` false the detector's own
    threshold is used unchanged. Returns (keypoints, descriptors, θ used).
    The detector keeps the last threshold set.
    """
    image = check_image(image)
    params = params or EnhanceParams()
    if min_keypoints is None:
        min_keypoints = params.min_keypoints
    if not params.adaptive_fast:
        kps, desc = orb.detectAndCompute(image, mask)
        return kps, desc, int(orb.getFastThreshold())
    theta = adaptive_fast_threshold(image, params.fast_omega)
    orb.setFastThreshold(theta)
    kps, desc = orb.detectAndCompute(image, mask)
    if len(kps) < min_keypoints:
        low = fallback_fast_threshold(image, params.fast_omega)
        if low < theta:
            orb.setFastThreshold(low)
            kps, desc = orb.detectAndCompute(image, mask)
            theta = low
    return kps, desc, theta
