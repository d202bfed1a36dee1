"""The denoiser's strength from the frame's signal-to-noise (issue 9; docs/notes/s15-snr.md).

Why: the self-guided filter's coefficient in a window of variance V is a = V / (V + ε) (He et al.,
"Guided Image Filtering", Eq. 5): a Wiener-like shrinkage with ε in the place of the noise power.
``auto`` sets ε = (2σ)², twice the Wiener value, so that FAST stops firing on noise. Whether that is
the right trade depends on how far the scene's texture stands above the noise, not on σ alone:

* dark-rows with the grid's noisy sensor at full light, and the day-loop at 15 % light: the
  strongest tenth of the texture at ¼ scale has ~9–10 × the noise variance there. (2σ)² still
  averages windows up to std ~2σ and flattens that texture (dark-rows' crowns: disparities biased
  long, trajectory 0.24 % short, docs/notes/s14-darkrows.md); ε = (1.25σ)² keeps it.
* haze-row and the day-loop at 6 % light: the strongest tenth is only ~1–3 × the noise variance at
  ¼ scale. There is little texture to keep, and a weaker filter leaves noise corners instead
  (haze-row 6 %: 96 → 13 % tracked with the σ-only rule of s14).

The two groups measure the same denoiser σ (after the gain: 14–30 both), so σ cannot tell them
apart; the ratio of texture to noise can, and it does not depend on the gain (both are lifted alike).

Measure (``texture_snr``): on the frame the denoiser gets (after AFE and the exposure curve), a copy
downsampled by ``denoise_snr_downsample`` with INTER_AREA (the scale of ORB's coarser pyramid levels;
averaging f² pixels divides a white noise's variance by f²), the variance in 3×3 windows, and its
``denoise_snr_quantile`` (the most textured windows, those FAST and the descriptors use). Its
texture part (the window variance minus the noise's share σ²/f² · 8/9, the 3×3 sample variance of
white noise) over the noise variance at that scale (σ²/f²) is the SNR. A frame of pure white noise
measures ~0.6 (the 90th percentile of a 3×3 sample variance, χ²₈/9, lies 0.6 over its mean).

Rule (``snr_eps_factor``): under s14-darkrows' σ gate (``denoise_noisy_sigma``: the sensor's noise,
not the clean presets' quantisation) the ε factor goes linearly from ``denoise_eps_factor`` (2) at
SNR ≤ ``denoise_snr_low`` to ``denoise_eps_factor_noisy`` (1.25) at SNR ≥ ``denoise_snr_high``; a
ramp, not a step, so that a frame near the threshold does not flip between two filters.
``denoise_snr_high`` 0 (the default) = off: s14's σ-only rule (``noisy_dark.denoise_eps_factor``).
Frames under the σ gate or under ``denoise_snr_low`` get exactly ``denoise_eps_factor``, the same
pixels as without the rule. Cost: one INTER_AREA resize to 1/16 of the pixels and two box filters,
only on frames over the σ gate (~0.4 ms thread CPU on a 752×480 frame, quiet).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.enhance.common import check_image, luma
from canopy.enhance.noise import _downsample
from canopy.enhance.noisy_dark import denoise_eps_factor
from canopy.enhance.params import EnhanceParams

_WINDOW = 3
_WHITE_SHARE = 1.0 - 1.0 / (_WINDOW * _WINDOW)  # E[sample variance of n white values] = (1 - 1/n)·var


def texture_snr(image: np.ndarray, sigma: float, downsample: int = 4, quantile: float = 0.9) -> float:
    """Texture variance over noise variance, both at 1/``downsample`` scale, in the ``quantile`` of the
    3×3-window variances (module doc). ``sigma``: the frame's noise std in grey levels at full
    resolution (> 0). 0 for images too small to measure."""
    image = check_image(image)
    if not (np.isfinite(sigma) and sigma > 0.0):
        raise ValueError(f"texture_snr: sigma must be a finite number > 0, got {sigma!r}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"texture_snr: quantile must be in (0, 1), got {quantile!r}")
    f = max(1, int(downsample))
    grey = luma(image)
    small = _downsample(grey, f)
    if small is grey:
        f = 1
    if min(small.shape) < _WINDOW:
        return 0.0
    k = (_WINDOW, _WINDOW)
    mean = cv2.boxFilter(small, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)
    var = cv2.subtract(cv2.sqrBoxFilter(small, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT), cv2.multiply(mean, mean))
    flat = var.ravel()
    q = float(np.partition(flat, int(quantile * (flat.size - 1)))[int(quantile * (flat.size - 1))])
    noise = float(sigma) ** 2 / (f * f)
    return (q - _WHITE_SHARE * noise) / noise


def snr_eps_factor(image: np.ndarray, sigma: float, params: EnhanceParams) -> float:
    """ε factor of the denoiser for the frame ``image`` (as the denoiser gets it) with noise σ ``sigma``:
    ``denoise_eps_factor`` under the σ gate; over it, s14's ``denoise_eps_factor_noisy`` when the SNR
    rule is off, else the ramp of the module doc between the two factors by ``texture_snr``."""
    gate_open = params.denoise_noisy_sigma > 0.0 and float(sigma) >= params.denoise_noisy_sigma
    if not gate_open or params.denoise_snr_high <= 0.0:
        return denoise_eps_factor(sigma, params)
    snr = texture_snr(image, sigma, params.denoise_snr_downsample, params.denoise_snr_quantile)
    lo, hi = params.denoise_snr_low, params.denoise_snr_high
    if snr <= lo:
        return params.denoise_eps_factor
    if snr >= hi:
        return params.denoise_eps_factor_noisy
    t = (snr - lo) / (hi - lo)
    return params.denoise_eps_factor + t * (params.denoise_eps_factor_noisy - params.denoise_eps_factor)


def lit_denoise_wanted(image: np.ndarray, sigma: float, params: EnhanceParams) -> bool:
    """With ``auto_denoise_lit``: whether a well-lit frame of noise σ ``sigma`` is denoised. σ must
    exceed ``auto_noise_sigma`` (s11's rule) and, with ``auto_denoise_lit_max_snr`` > 0, the frame's
    ``texture_snr`` must be at most that: haze scales the texture by the transmission t and leaves the
    sensor noise as it is, so a hazy noisy frame has less texture over its noise than a clear noisy
    one (docs/notes/s16-darkhaze.md); s11-haze found the denoiser helped the generated presets' lit
    hazy noisy cells but broke the clear noisy day-loop (6.7 -> 16.5 mm)."""
    if not float(sigma) > params.auto_noise_sigma:
        return False
    if params.auto_denoise_lit_max_snr <= 0.0:
        return True
    snr = texture_snr(image, sigma, params.denoise_snr_downsample, params.denoise_snr_quantile)
    return snr <= params.auto_denoise_lit_max_snr
