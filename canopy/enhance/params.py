"""Parameters of the enhancement stage (one frozen dataclass, papers' values as defaults).

Sources of the defaults:
- AGRI-SLAM §3.1: ``omega`` = 0.8, ``block`` (Ω) = 9, ``n_dark_pixels`` = 200.
  ``t0`` is not in the paper; 0.1 is He et al.'s lower bound on the
  transmission (dark channel prior), needed so Eq. 4 never divides by ~0.
- AFE-ORB-SLAM §4: ``tau`` = 0.3 (Eq. 9), ``low_contrast_lambda`` = 0.25
  (Eq. 1/17), ``usm_alpha`` = 1.0 and ``usm_beta`` = 0.3 (Eq. 17),
  ``fast_omega`` = 128 (Eq. 18–19). The paper gives neither the weighting
  exponent ``i`` of Eq. 3 nor the Gaussian σ of Eq. 16: ``wd_exponent`` = 0.75
  is Cao et al.'s IAGCWD value for the truncated (dimmed-image) branch that
  Algorithm 1 describes; ``usm_sigma`` = 1.0 is scikit-image's
  ``unsharp_mask`` default radius.
- CLAHE baseline: OpenCV's clip limit 2.0 and 8×8 tiles.
- ``auto_*`` thresholds are ours (see ``canopy.enhance.auto``), chosen from
  the statistics of the real images in ``../shared/data``: EuRoC V1_01 grey
  mean 145 / std 53, KITTI 06 mean 93 / std 60, O-HAZE hazy photos mean 140 /
  std 22 / dark channel 126–131, LOL/LIME/DICM low-light photos mean 6–45.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from shared.errors import ConfigError

ENHANCE_METHODS = ("none", "he", "clahe", "afe", "agri", "auto")
# What ``auto`` may decide per frame ("dehaze" = dark channel prior on the image itself).
AUTO_DARK_METHODS = ("afe", "agri")
# "X>dn": X, then the noise-aware denoiser (canopy.enhance.noise).
AUTO_DECISIONS = ("none", "agri", "dehaze", "afe", "none>dn", "agri>dn", "dehaze>dn", "afe>dn")


@dataclass(frozen=True)
class EnhanceParams:
    method: str = "none"
    # AGRI §3.1, Eq. 1–5
    omega: float = 0.8
    block: int = 9
    n_dark_pixels: int = 200
    t0: float = 0.1
    # AFE §4.1, Eq. 1–17
    tau: float = 0.3
    wd_exponent: float = 0.75
    low_contrast_lambda: float = 0.25
    usm_alpha: float = 1.0
    usm_beta: float = 0.3
    usm_sigma: float = 1.0
    afe_hist_row_step: int = 2       # Eq. 2's histogram from every n-th row (speed; 1 = every row)
    # CLAHE baseline
    clahe_clip: float = 2.0
    clahe_tiles: int = 8
    # auto (ours): statistics on a copy downsampled by ``auto_downsample``
    auto_downsample: int = 4
    auto_dark_mean: float = 60.0     # mean grey below this: under-exposed -> auto_dark_method
    auto_dark_method: str = "afe"    # agri | afe: what under-exposed frames get (see canopy.enhance.auto)
    auto_bright_mean: float = 200.0  # mean grey above this: over-exposed -> afe
    auto_low_std: float = 28.0       # std (downsampled copy) below this: low contrast
    auto_haze_dark: float = 100.0    # mean dark channel at/above this (with low std): hazy -> dehaze
    auto_dehaze_max_clip: float = 0.02  # dehazing may clip at most this much more of the frame, else afe
    auto_denoise_lit: bool = False   # also denoise well-lit frames (see canopy.enhance.auto, rule 3)
    auto_noise_sigma: float = 4.0    # with auto_denoise_lit: noise σ (grey levels) above this -> denoise
    # with auto_denoise_lit: ... and only frames whose texture_snr (canopy.enhance.snr) is at most this
    # (haze lowers it, docs/notes/s16-darkhaze.md); 0: no texture test
    auto_denoise_lit_max_snr: float = 0.0
    auto_dark_min_sigma: float = 4.0  # under-exposed frames (agri) are always denoised, with σ at least this
    auto_dark_target_mean: float = 60.0   # under-exposed frames: power curve to this mean grey before denoising (0: off)
    auto_dark_min_gamma: float = 0.4      # ... with γ at least this (bounds the gain on the darkest levels)
    # noise-aware denoising (ours, canopy.enhance.noise): Immerkær/MAD noise σ, self-guided filter
    denoise_radius: int = 2          # px at full resolution (window 5×5)
    denoise_eps_factor: float = 2.0  # ε = (factor·σ)²: windows with std below ~2σ count as flat
    noise_rows_fraction: float = 0.5  # the noise σ is estimated on this central band of rows (speed)
    # s14-darkrows (canopy.enhance.noisy_dark): frames whose denoiser σ is >= denoise_noisy_sigma
    # (0 = off) get ε = (denoise_eps_factor_noisy·σ)² instead
    denoise_noisy_sigma: float = 0.0
    denoise_eps_factor_noisy: float = 2.0
    # s15-snr (canopy.enhance.snr): over that σ gate, the factor follows the frame's texture SNR (top
    # ``denoise_snr_quantile`` of the 3×3-window variances at 1/``denoise_snr_downsample`` scale over the
    # noise variance there): denoise_eps_factor at SNR <= denoise_snr_low, denoise_eps_factor_noisy at
    # >= denoise_snr_high, linear between; denoise_snr_high 0 = off (s14's σ-only rule)
    denoise_snr_low: float = 0.0
    denoise_snr_high: float = 0.0
    denoise_snr_downsample: int = 4
    denoise_snr_quantile: float = 0.9
    # threads for the two images of a pair (canopy.enhance.pair): 1 = one after the other. OpenCV
    # already spreads the big filters over the cores, and on a busy machine (the pipeline's other
    # actors) a second thread only adds CPU (dark KITTI pair: 5.1 vs 4.7 ms CPU at load 8); 2 pays
    # only with an idle core (docs/enhancement-noise.md, speed)
    pair_threads: int = 1
    # AFE §4.2, Eq. 18–19
    adaptive_fast: bool = True
    fast_omega: float = 128.0
    min_keypoints: int = 200  # fewer keypoints than this at Eq. 18's θ: retry with Eq. 19's θ
    # on denoised (under-exposed) frames retry with Eq. 19 below the tracker's whole feature budget
    # (canopy.enhance.fast.tracking_fast_arguments)
    fill_denoised_features: bool = True
    denoised_fallback_weight: float = 0.0  # that retry's θ: w·Eq. 18 + (1 − w)·Eq. 19

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        def bad(name: str, why: str):
            raise ConfigError(f"EnhanceParams.{name}", f"{why}, got {getattr(self, name)!r}")

        for name in ("omega", "t0", "tau", "wd_exponent", "low_contrast_lambda", "usm_alpha",
                     "usm_beta", "usm_sigma", "clahe_clip", "auto_dark_mean", "auto_bright_mean",
                     "auto_low_std", "auto_haze_dark", "fast_omega", "denoise_eps_factor",
                     "auto_dehaze_max_clip", "auto_noise_sigma", "auto_dark_min_sigma", "noise_rows_fraction",
                     "auto_dark_target_mean", "auto_dark_min_gamma",
                     "denoised_fallback_weight", "denoise_noisy_sigma", "denoise_eps_factor_noisy",
                     "denoise_snr_low", "denoise_snr_high", "denoise_snr_quantile", "auto_denoise_lit_max_snr"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                bad(name, "must be a finite number")
        for name in ("block", "n_dark_pixels", "clahe_tiles", "auto_downsample", "min_keypoints", "denoise_radius",
                     "afe_hist_row_step", "pair_threads", "denoise_snr_downsample"):
            if isinstance(getattr(self, name), bool) or not isinstance(getattr(self, name), int):
                bad(name, "must be an integer")
        for name in ("adaptive_fast", "auto_denoise_lit", "fill_denoised_features"):
            if not isinstance(getattr(self, name), bool):
                bad(name, "must be true or false")
        if self.auto_dark_method not in AUTO_DARK_METHODS:
            bad("auto_dark_method", f"must be one of {', '.join(AUTO_DARK_METHODS)}")
        if self.method not in ENHANCE_METHODS:
            bad("method", f"must be one of {', '.join(ENHANCE_METHODS)}")
        if not 0.0 < self.omega <= 1.0:
            bad("omega", "must be in (0, 1]")
        if self.block < 1 or self.block % 2 == 0:
            bad("block", "must be a positive odd integer")
        if self.n_dark_pixels < 1:
            bad("n_dark_pixels", "must be >= 1")
        if not 0.0 < self.t0 <= 1.0:
            bad("t0", "must be in (0, 1]")
        if not 0.0 <= self.tau <= 1.0:
            bad("tau", "must be in [0, 1]")
        if not self.wd_exponent > 0.0:
            bad("wd_exponent", "must be > 0")
        if not 0.0 <= self.low_contrast_lambda <= 1.0:
            bad("low_contrast_lambda", "must be in [0, 1]")
        for name in ("usm_alpha", "usm_beta"):
            if not getattr(self, name) >= 0.0:
                bad(name, "must be >= 0")
        if not self.usm_sigma > 0.0:
            bad("usm_sigma", "must be > 0")
        if not self.clahe_clip > 0.0:
            bad("clahe_clip", "must be > 0")
        if self.clahe_tiles < 1:
            bad("clahe_tiles", "must be >= 1")
        if self.auto_downsample < 1:
            bad("auto_downsample", "must be >= 1")
        for name in ("auto_dark_mean", "auto_bright_mean", "auto_haze_dark"):
            if not 0.0 <= getattr(self, name) <= 255.0:
                bad(name, "must be in [0, 255]")
        if not self.auto_dark_mean <= self.auto_bright_mean:
            bad("auto_dark_mean", f"must not exceed auto_bright_mean ({self.auto_bright_mean})")
        if not 0.0 <= self.auto_dehaze_max_clip <= 1.0:
            bad("auto_dehaze_max_clip", "must be in [0, 1]")
        for name in ("auto_noise_sigma", "auto_dark_min_sigma"):
            if not getattr(self, name) >= 0.0:
                bad(name, "must be >= 0")
        if not self.auto_low_std >= 0.0:
            bad("auto_low_std", "must be >= 0")
        if self.pair_threads not in (1, 2):
            bad("pair_threads", "must be 1 or 2")
        if self.afe_hist_row_step < 1:
            bad("afe_hist_row_step", "must be >= 1")
        if self.denoise_radius < 1:
            bad("denoise_radius", "must be >= 1")
        if not 0.0 <= self.auto_dark_target_mean <= 255.0:
            bad("auto_dark_target_mean", "must be in [0, 255]")
        if not 0.0 < self.auto_dark_min_gamma <= 1.0:
            bad("auto_dark_min_gamma", "must be in (0, 1]")
        if not 0.0 <= self.denoised_fallback_weight <= 1.0:
            bad("denoised_fallback_weight", "must be in [0, 1]")
        if not 0.0 < self.noise_rows_fraction <= 1.0:
            bad("noise_rows_fraction", "must be in (0, 1]")
        if not self.denoise_eps_factor > 0.0:
            bad("denoise_eps_factor", "must be > 0")
        if not self.denoise_eps_factor_noisy > 0.0:
            bad("denoise_eps_factor_noisy", "must be > 0")
        if not self.denoise_noisy_sigma >= 0.0:
            bad("denoise_noisy_sigma", "must be >= 0 (0 = off)")
        if not self.denoise_snr_low >= 0.0:
            bad("denoise_snr_low", "must be >= 0")
        if not self.denoise_snr_high >= 0.0:
            bad("denoise_snr_high", "must be >= 0 (0 = off)")
        if self.denoise_snr_high > 0.0 and not self.denoise_snr_high > self.denoise_snr_low:
            bad("denoise_snr_high", f"must exceed denoise_snr_low ({self.denoise_snr_low}) when on")
        if self.denoise_snr_downsample < 1:
            bad("denoise_snr_downsample", "must be >= 1")
        if not 0.0 < self.denoise_snr_quantile < 1.0:
            bad("denoise_snr_quantile", "must be in (0, 1)")
        if not self.fast_omega > 0.0:
            bad("fast_omega", "must be > 0")
        if self.min_keypoints < 0:
            bad("min_keypoints", "must be >= 0")
