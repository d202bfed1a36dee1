"""``auto``: our own per-frame choice of enhancement from cheap statistics.

AGRI enhances only under-exposed frames; AFE's own enhancement already
branches on brightness and contrast. ``auto`` makes that choice explicit and
leaves well-lit frames untouched. Statistics come from a copy downsampled by
``auto_downsample`` (INTER_AREA): grey mean, grey std and the mean of the dark
channel (min over channels and a block of ``block // auto_downsample`` rounded
up to odd, i.e. the paper's Ω at the reduced scale).

Decision, first rule that fires:

1. mean < ``auto_dark_mean``                              -> ``auto_dark_method``
   (under-exposed. Default ``afe``: on the degradation grid of
   ``benchmarks/bench_enhance_features.py`` (6 sequences, 24 cells of light
   × haze × noise) AFE's curve followed by the denoiser gave the most
   correct stereo matches, 0.76 of the best candidate's on average against
   0.70 for AGRI's inverted dehazing + denoiser, and clearly more at low
   noise, e.g. 173 vs 140 matches at 6 % light, β 0.06. ``agri`` is the
   paper's choice and gives the better picture: LOL PSNR 11.41 vs 10.40 dB).
2. std < ``auto_low_std`` and dark ≥ ``auto_haze_dark``   -> ``dehaze``
   (bright, flat and with a high dark channel: haze. Haze is what the dark
   channel prior models, so we dehaze the image itself rather than use AFE's
   gamma, which only redistributes grey levels and cannot remove the
   additive airlight A(1 − t)).
3. std < ``auto_low_std`` or mean > ``auto_bright_mean``  -> ``afe``
   (low contrast without haze, or over-exposure: AFE's truncated AGCWD handles
   both dimmed and bright frames, via the negative image for the latter).
4. otherwise                                              -> ``none``.

Then the noise step (``auto_full``): a guard against dehazing what the
dark channel prior does not model, and the noise-aware denoiser
(``canopy.enhance.noise``) after the enhancement when the treated frame's
noise σ says FAST would fire on noise; the decision becomes ``X>dn``.

On the real data here (statistics at 1/4 scale): EuRoC V1_01 (mean 145,
std 53) and KITTI 06 (93, 60) and the O-HAZE clear references (101–103,
30–43) stay ``none``; the O-HAZE hazy photos (140–143, std 15–20, dark
126–131) go ``dehaze``; LOL, LIME and most DICM photos (mean 6–45) go
the dark branch.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from canopy.enhance.agcwd import agcwd_unsharp
from canopy.enhance.common import check_image, luma, on_luma
from canopy.enhance.dehaze import dark_channel, dehaze_dark_channel, dehaze_inverted
from canopy.enhance.noise import estimate_noise
from canopy.enhance.noisy_dark import denoise_frame  # s14-darkrows hook: the ε factor by σ
from canopy.enhance.params import EnhanceParams
from canopy.enhance.snr import lit_denoise_wanted, snr_eps_factor  # s15-snr: the ε factor by the frame's texture SNR; s16: lit frames


def auto_statistics(image: np.ndarray, params: EnhanceParams) -> dict:
    """mean, std (grey) and mean dark channel of a downsampled copy."""
    f = params.auto_downsample
    h, w = image.shape[:2]
    small = image
    if f > 1 and h >= f and w >= f:
        # crop to whole f×f cells so INTER_AREA takes its fast integer-factor path
        whole = image[: h - h % f, : w - w % f]
        small = cv2.resize(whole, (w // f, h // f), interpolation=cv2.INTER_AREA)
    m, s = cv2.meanStdDev(luma(small))
    block = max(1, params.block // f)
    block += 1 - block % 2
    dark = float(cv2.mean(dark_channel(small, block))[0])
    return {"mean": float(m[0, 0]), "std": float(s[0, 0]), "dark": dark}


def auto_decide(image: np.ndarray, params: EnhanceParams | None = None) -> tuple[str, dict]:
    """The decision name (one of AUTO_DECISIONS) and the statistics it was made from."""
    image = check_image(image)
    params = params or EnhanceParams()
    st = auto_statistics(image, params)
    low_contrast = st["std"] < params.auto_low_std
    if st["mean"] < params.auto_dark_mean:
        return params.auto_dark_method, st
    if low_contrast and st["dark"] >= params.auto_haze_dark:
        return "dehaze", st
    if low_contrast or st["mean"] > params.auto_bright_mean:
        return "afe", st
    return "none", st


_APPLY = {
    "none": lambda image, params: image,
    "agri": dehaze_inverted,
    "dehaze": dehaze_dark_channel,
    "afe": agcwd_unsharp,
}


def _clipped_fraction(image: np.ndarray) -> float:
    """Fraction of grey levels at 0 or 255 (on luma)."""
    grey = luma(image)
    hist = cv2.calcHist([grey], [0], None, [256], [0, 256]).ravel()
    return float((hist[0] + hist[255]) / grey.size)


def exposure_gamma(image: np.ndarray, target_mean: float, min_gamma: float) -> float:
    """γ ≤ 1 of the power curve 255·(l/255)^γ that takes the mean grey m of ``image`` to
    ``target_mean`` (1 when m is already there, when the target is 0 = off, or when the frame
    is black); at least ``min_gamma``, which bounds the gain on the darkest levels."""
    m = float(cv2.mean(luma(image))[0])
    if target_mean <= 0.0 or m >= target_mean or m < 0.5:
        return 1.0
    return max(float(min_gamma), math.log(target_mean / 255.0) / math.log(m / 255.0))


def apply_gamma(image: np.ndarray, gamma: float) -> np.ndarray:
    """The power curve 255·(l/255)^γ as an 8-bit LUT (on luma for colour); γ = 1: unchanged."""
    if gamma == 1.0:
        return image
    lut = np.clip(np.rint(255.0 * (np.arange(256) / 255.0) ** gamma), 0, 255).astype(np.uint8)
    return on_luma(image, lambda g: cv2.LUT(g, lut))


def apply_decision(image: np.ndarray, decision: str, params: EnhanceParams,
                   noise_sigma: float | None = None, gamma: float = 1.0,
                   eps_factor: float | None = None) -> tuple[np.ndarray, float]:
    """Apply an ``auto`` decision (one of AUTO_DECISIONS) to ``image``.

    ``X>dn``: method X, the exposure curve of power ``gamma`` (``auto_full``
    step 3; 1 = none), then ``denoise`` with the noise σ measured on that
    (or ``noise_sigma`` when given: the right image of a pair gets the left
    image's σ and γ, so both are treated alike). Returns (image, σ used; 0
    when nothing was denoised).
    """
    base, _, post = decision.partition(">")
    out = _APPLY[base](image, params)
    if post != "dn":
        return out, 0.0
    out = apply_gamma(out, gamma)
    sigma = estimate_noise(out, rows_fraction=params.noise_rows_fraction) if noise_sigma is None \
        else float(noise_sigma)
    factor = snr_eps_factor(out, sigma, params) if eps_factor is None else float(eps_factor)
    return denoise_frame(out, sigma, params, factor), sigma


def auto_full(image: np.ndarray, params: EnhanceParams | None = None) -> tuple[np.ndarray, str, float]:
    """``auto`` with its noise step: (image, decision, σ used for denoising or 0); the steps
    are those of ``auto_treat``, which also returns the exposure γ."""
    out, decision, sigma, _ = auto_treat(image, params)
    return out, decision, sigma


def auto_treat(image: np.ndarray, params: EnhanceParams | None = None) -> tuple[np.ndarray, str, float, float]:
    """``auto``: (image, decision, σ used for denoising or 0, exposure γ or 1); ``auto_treat_factor``'s
    first four."""
    return auto_treat_factor(image, params)[:4]


def auto_treat_factor(image: np.ndarray, params: EnhanceParams | None = None
                      ) -> tuple[np.ndarray, str, float, float, float]:
    """``auto``: (image, decision, σ used for denoising or 0, exposure γ or 1, the denoiser's ε factor
    or 0; ``canopy.enhance.snr``).

    1. The base decision of ``auto_decide`` (darkness, haze, contrast).
    2. Haze guard: the dark channel prior fails on scenes it does not model
       (large bright surfaces, sky), where it over-darkens and clips. If
       dehazing clips more than ``auto_dehaze_max_clip`` more of the pixels
       than the input had, AFE's AGCWD is used instead (it only redistributes
       grey levels, so it cannot invent a wrong transmission).
    3. Noise: under-exposed frames (rule 1) are always denoised (decision
       ``X>dn``), with the noise σ of the treated image (``estimate_noise``:
       the enhancement has already amplified the noise by its gain, which is
       what FAST sees), at least ``auto_dark_min_sigma``. Well-lit frames are
       denoised only with ``auto_denoise_lit`` and σ above
       ``auto_noise_sigma``; off by default, because on the grid denoising
       lit frames cost correct matches under haze (168 vs 220 at β 0.06,
       the guided filter flattens texture whose contrast the haze has brought
       down to the noise level) and in SLAM gained nothing without haze
       (KITTI at full light, high noise: 0.072 m none vs 0.082 m denoised).
       Clean frames measure σ 1.7–2.7 (texture and the real sensor noise of
       EuRoC / KITTI / the generated scenes).
       Under-exposed frames (rule 1) are always denoised, with σ at least
       ``auto_dark_min_sigma``: at a few grey levels of signal the frame is
       quantised as much as it is noisy, the MAD estimate then sees flat
       steps (σ 2.5 on a frame at 2 % light whose noise the enhancement has
       raised ten-fold), and on the degradation grid the denoised variant of
       each method found more correct stereo matches than the method alone
       in every dark cell but one (``benchmarks/bench_enhance_features.py``).
       Before the denoiser, under-exposed frames get an exposure curve, the power γ that takes
       their mean grey to ``auto_dark_target_mean`` (``exposure_gamma``, γ ≥
       ``auto_dark_min_gamma``): AFE's truncated curve lifts a frame at 2–15 % light only
       from a mean of ~6–15 to ~20–30, so the denoiser's averages would be rounded back into a
       few dozen grey levels; brightened first, they keep their precision. It also gives the
       picture a normal exposure (LOL pair 778: 10.4 dB without it).
    """
    image = check_image(image)
    params = params or EnhanceParams()
    decision, st = auto_decide(image, params)
    dark = st["mean"] < params.auto_dark_mean
    out = _APPLY[decision](image, params)
    if decision == "dehaze" and \
            _clipped_fraction(out) - _clipped_fraction(image) > params.auto_dehaze_max_clip:
        decision = "afe"
        out = _APPLY[decision](image, params)
    if not dark and not params.auto_denoise_lit:
        return out, decision, 0.0, 1.0, 0.0
    gamma = 1.0
    if dark:
        gamma = exposure_gamma(out, params.auto_dark_target_mean, params.auto_dark_min_gamma)
        out = apply_gamma(out, gamma)
    sigma = estimate_noise(out, rows_fraction=params.noise_rows_fraction)
    if dark:
        sigma = max(sigma, params.auto_dark_min_sigma)
    if dark or (params.auto_denoise_lit and lit_denoise_wanted(out, sigma, params)):
        factor = snr_eps_factor(out, sigma, params)
        return denoise_frame(out, sigma, params, factor), decision + ">dn", sigma, gamma, factor
    return out, decision, 0.0, 1.0, 0.0


def auto(image: np.ndarray, params: EnhanceParams | None = None) -> tuple[np.ndarray, str]:
    """Enhance as ``auto`` decides (``auto_full``); returns (image, decision_name)."""
    out, decision, _ = auto_full(image, params)
    return out, decision
