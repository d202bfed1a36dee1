"""Sensor-noise level of a frame and an edge-preserving denoiser (issue 9, item 1).

Noise estimate (``estimate_noise``)
    Immerkær's fast noise variance estimation (J. Immerkær, "Fast Noise
    Variance Estimation", CVIU 64(2), 1996): the 3×3 mask

        N = [[1, −2, 1], [−2, 4, −2], [1, −2, 1]]

    (the difference of two Laplacians) cancels locally planar image
    structure, and on white Gaussian noise of σ the response I * N has
    standard deviation 6σ (‖N‖₂ = 6). Immerkær averages |I * N| over the whole
    image (σ = √(π/2)·mean|I*N| / 6), which counts edges and texture as noise.
    We take the robust version instead: σ = median|I * N| / (0.6745 · 6), the
    median absolute response of a Gaussian being 0.6745 of its std (the MAD
    estimator Donoho & Johnstone use on wavelet detail coefficients), so the
    minority of pixels on edges and corners does not move it.

    Cost: it runs on a copy downsampled by ``noise_downsample`` with
    INTER_AREA (averaging f² independent pixels divides a white noise's σ by
    f, so the estimate is multiplied back by f; default 1, because at 1/2
    scale texture already inflates the estimate), and the median is taken
    from a 256-bin histogram of |I * N| rather than a sort. Responses
    saturate at 127.5, so σ saturates at ~31 grey levels.

    Shot noise is not white in level (its variance grows with the signal)
    but it is white in space, which is all the estimator needs: the result is
    the noise std in grey levels at the frame's typical brightness.

Denoiser (``denoise``)
    What tracking needs from a denoiser is that FAST stops firing on noise
    while real corners stay put. A self-guided filter (He, Sun & Tang,
    "Guided Image Filtering", ECCV 2010, Eq. 2–8 with guide = input) is an
    edge-preserving smoother: in a (2r+1)² window with variance σ_w² it
    outputs a·I + b with a = σ_w² / (σ_w² + ε), so windows whose variance is
    at the noise level (flat areas) are averaged and windows with real
    structure (σ_w² ≫ ε) keep it. We set ε = (``eps_factor`` · σ)²
    from the measured σ, which is what makes it noise-aware. The coefficients
    are computed at half resolution (He & Sun's fast guided filter): a few
    box filters, O(1) per pixel whatever r is; the full-resolution step
    (upsampling ā, b̄ and q = ā·I + b̄) runs in 8-bit fixed point.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.enhance.common import check_image, luma, on_luma

# Immerkær's mask (the difference of two discrete Laplacians).
IMMERKAER_MASK = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
IMMERKAER_NORM = 6.0          # ‖N‖₂ = sqrt(1+4+1+4+16+4+1+4+1)
MAD_TO_SIGMA = 1.0 / 0.6745   # median |x| of N(0, σ²) is 0.6745 σ
_HIST_STEP = 1.0              # |I*N| histogram bin width (grey levels): 256 bins cover responses < 256


def _downsample(image: np.ndarray, factor: int) -> np.ndarray:
    h, w = image.shape[:2]
    if factor <= 1 or h < 3 * factor or w < 3 * factor:
        return image
    whole = image[: h - h % factor, : w - w % factor]  # integer-factor INTER_AREA is a plain block mean
    return cv2.resize(whole, (w // factor, h // factor), interpolation=cv2.INTER_AREA)


def estimate_noise(image: np.ndarray, downsample: int = 1, rows_fraction: float = 1.0) -> float:
    """Noise std (grey levels, full resolution) of a uint8 grey or BGR image; 0 for images < 3×3.

    Robust Immerkær estimate (module doc) on a copy downsampled by ``downsample``, from the
    central band of ``rows_fraction`` of the rows (the noise is white in space, so a band of
    ~10⁵ pixels gives the same median at a fraction of the cost; 1 = the whole frame).
    """
    image = check_image(image)
    grey = luma(image)
    if 0.0 < rows_fraction < 1.0:
        h = grey.shape[0]
        keep = max(3, int(round(h * rows_fraction)))
        top = (h - keep) // 2
        grey = grey[top:top + keep]
    f = int(downsample) if downsample and downsample > 1 else 1
    small = _downsample(grey, f)
    if small is grey:
        f = 1
    if min(small.shape) < 3:
        return 0.0
    resp = cv2.filter2D(small, cv2.CV_16S, IMMERKAER_MASK, borderType=cv2.BORDER_REPLICATE)
    # |I*N| / _HIST_STEP as uint8 (saturating): the median from a 256-bin histogram, no sort
    levels = cv2.convertScaleAbs(resp[1:-1, 1:-1], alpha=1.0 / _HIST_STEP)
    hist = cv2.calcHist([levels], [0], None, [256], [0, 256]).ravel()
    cum = np.cumsum(hist)
    half = 0.5 * levels.size
    k = int(np.searchsorted(cum, half))
    if k >= 255:  # half the responses saturate: at least this much noise
        median = 255 * _HIST_STEP
    else:
        below = cum[k - 1] if k > 0 else 0.0
        frac = (half - below) / max(hist[k], 1.0)  # linear interpolation inside the bin
        median = (k - 0.5 + frac) * _HIST_STEP  # bin k holds responses rounded to k
    return float(median * MAD_TO_SIGMA / IMMERKAER_NORM * f)


def guided_self_filter(grey: np.ndarray, radius: int, eps: float, subsample: int = 2) -> np.ndarray:
    """He et al.'s guided filter with the image as its own guide (Eq. 2–8); uint8 in, uint8 out.

    The fast guided filter (He & Sun, arXiv:1505.00996): the linear
    coefficients (a, b) are computed on a copy subsampled by ``subsample``
    with radius ``radius / subsample``, upsampled bilinearly, and applied to
    the full-resolution image (q = ā·I + b̄), so the edges stay those of I.
    """
    h, w = grey.shape
    s = int(subsample) if subsample > 1 and h >= 4 * subsample and w >= 4 * subsample else 1
    r = max(1, int(round(radius / s)))
    ksize = (2 * r + 1, 2 * r + 1)
    small = _downsample(grey, s) if s > 1 else grey
    mean_i = cv2.boxFilter(small, cv2.CV_32F, ksize)
    mean_ii = cv2.sqrBoxFilter(small, cv2.CV_32F, ksize)
    var_i = cv2.subtract(mean_ii, cv2.multiply(mean_i, mean_i))
    # cv2 division: numpy's float32 division is several times slower here. The + ε in numpy: cv2.add
    # with a Python scalar is ambiguous on a 1x1 (OpenCV 5.1: 4x1 result) or 4x1 image (5.0: error)
    a = cv2.divide(var_i, var_i + np.float32(eps))          # Eq. 5 with p = I
    b = cv2.subtract(mean_i, cv2.multiply(a, mean_i))         # Eq. 6
    mean_a = cv2.boxFilter(a, -1, ksize)
    mean_b = cv2.boxFilter(b, -1, ksize)
    # Eq. 8 in 8-bit fixed point: 0 ≤ ā ≤ 1 in steps of 1/255 and 0 ≤ b̄ = mean − ā·mean ≤ 255 in
    # whole grey levels, so the upsampling and the full-resolution product run on 8-bit images
    # (the result is within two grey levels of the float filter, 0.3 on average; float maps cost
    # ~2× here)
    a8 = cv2.convertScaleAbs(mean_a, alpha=255.0)
    b8 = cv2.convertScaleAbs(mean_b)
    if s > 1:
        a8 = cv2.resize(a8, (w, h), interpolation=cv2.INTER_LINEAR)
        b8 = cv2.resize(b8, (w, h), interpolation=cv2.INTER_LINEAR)
    # ā·I ≤ I ≤ 255 fits 8 bits and is rounded either way, so the product goes straight to uint8
    # (the same pixels as a 16-bit product, ~5× cheaper), then + b̄ saturated to [0, 255]
    q = cv2.multiply(a8, grey, scale=1.0 / 255.0)
    return cv2.add(q, b8)


def denoise(image: np.ndarray, sigma: float, radius: int = 2, eps_factor: float = 2.0, subsample: int = 2) -> np.ndarray:
    """Noise-aware edge-preserving smoothing: self-guided filter with ε = (eps_factor·σ)².

    ``sigma``: the frame's noise std in grey levels (``estimate_noise``); σ ≤ 0
    returns the image unchanged. Colour images are filtered on luma.
    """
    image = check_image(image)
    if not sigma > 0.0:
        return image
    eps = float(eps_factor * sigma) ** 2
    return on_luma(image, lambda g: guided_self_filter(g, int(radius), eps, subsample))
