"""Front-end rules for hazy and noisy frames (issue 9): how strict stereo matching must be, which
pair the sub-pixel refinement runs on, and which extractor a noisy image gets (``NoiseGatedExtractor``).

Why (measured on KITTI 06 with haze β 0.06 /m and the grid's sensors, docs/notes/s4-dark.md):
haze lowers the contrast of every patch by the transmission t (Koschmieder), sensor noise
adds a fixed σ. Stereo matching refines each descriptor match by SAD correlation of an
(2w+1)² patch and rejects matches whose SAD exceeds ``sad_outlier_factor`` × the frame's
median SAD (ORB-SLAM2's ComputeStereoMatches: 1.5 × 1.4). That rule is relative: on a
low-contrast frame the correct matches have small SADs *and so do the wrong ones* — the
SAD no longer separates them, and the factor 2.1 lets through matches 1 px or more off the
true disparity (27 % of the matches on the hazy noisy cell, 13 % clean; far points, where
haze is thickest, 100 %). Those depths become landmarks and bend the trajectory (ATE 3–7×
the clean run, with 1–2 % scale error).

The signal-to-noise ratio of the matching is visible in the frame itself: the median SAD per
pixel of the accepted matches over the image noise σ (Immerkær estimate,
``track_health.image_noise_sigma``). Clean KITTI measures ~3.7, noise alone ~2.7, haze +
low-noise sensor ~2.5, haze + noisy sensor ~1.7. ``sad_acceptance_factor`` lowers the factor
linearly from ``sad_outlier_factor`` (SNR ≥ ``sad_snr_high``, 4.5) to ``sad_outlier_factor_noisy``
(SNR ≤ ``sad_snr_low``, 1.5): a frame whose SAD is close to the noise level accepts only matches
close to the median. Clean KITTI (SNR ~3.7, the σ estimate also sees fine texture) gets ~1.97,
clean EuRoC keeps 2.1 (identical ATE); the matches the stricter rule removes on a hazy noisy
pair are wrong twice as often as the ones it keeps (tests/test_noisy_stereo.py).

**Off by default** (``sad_outlier_factor_noisy`` = ``sad_outlier_factor``): the SNR measure does not
separate haze from fine synthetic texture — the generated orchard's *clean* frames measure SNR
~1.5 (haze-row ~1.1), get the strict factor, and day-loop's ATE rises 7.4 → 11.3 mm. Turn it on
(``sad_outlier_factor_noisy: 1.5``) only where the clean frames measure a high SNR (KITTI 3.7,
EuRoC 4.6).
"""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from canopy.enhance.noise import denoise, estimate_noise
from canopy.frontend.cell_extractor import CellExtractor, make_extractor
from canopy.frontend.features import OrbExtractor
from canopy.frontend.level_noise_extractor import LevelNoiseCellExtractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.track_health import image_noise_sigma


def sad_snr(median_sad: float, half_window: int, noise_sigma: float) -> float:
    """Median SAD per patch pixel over the noise sigma (inf when the noise is unknown or 0)."""
    if noise_sigma is None or not np.isfinite(noise_sigma) or noise_sigma <= 0:
        return float("inf")
    n_pixels = (2 * half_window + 1) ** 2
    return float(median_sad) / n_pixels / float(noise_sigma)


def sad_acceptance_factor(median_sad: float, noise_sigma: float | None, params: TrackingParams) -> float:
    """SAD outlier factor for one frame: ``sad_outlier_factor`` at high SNR, down to
    ``sad_outlier_factor_noisy`` at low SNR (linear in between; see the module docstring)."""
    hi, lo = params.sad_outlier_factor, params.sad_outlier_factor_noisy
    if noise_sigma is None or lo >= hi:
        return hi
    snr = sad_snr(median_sad, params.subpixel_window, noise_sigma)
    a = (snr - params.sad_snr_low) / (params.sad_snr_high - params.sad_snr_low)
    return float(lo + (hi - lo) * np.clip(a, 0.0, 1.0))


def accept_sad(sad: np.ndarray, params: TrackingParams, noise_sigma: float | None = None) -> np.ndarray:
    """Mask of stereo matches to keep: SAD ≤ factor × median SAD, the factor from the frame's SNR."""
    if len(sad) == 0:
        return np.zeros(0, bool)
    med = float(np.median(sad))
    return sad <= sad_acceptance_factor(med, noise_sigma, params) * med


def refinement_pair(left_img: np.ndarray, right_img: np.ndarray, params: TrackingParams,
                    left_sigma: float | None = None):
    """The image pair the SAD sub-pixel refinement runs on, and the left image's robust noise σ
    (None when not measured: ``subpixel_denoise_sigma`` 0 = off). ``left_sigma``: that σ when the
    extractor already measured it (``Features.robust_noise_sigma``), else it is measured here.

    Why: on a noisy sensor the SAD costs around the minimum carry the noise of both 11×11 patches,
    so the parabola's vertex (the sub-pixel disparity) scatters, most for far points whose
    disparity is a few px. Smoothing both images with the same symmetric kernel leaves the true
    disparity where it is (a horizontal shift commutes with the convolution) and averages the
    noise of each pixel with its neighbours'. Only the refinement sees the smoothed pair:
    keypoints and descriptors stay those of the raw frame. The σ is the robust Immerkær / MAD
    estimate (canopy.enhance.noise.estimate_noise), which texture barely moves: clean KITTI /
    EuRoC frames measure ≤ 2.0, the generated ones ≤ 3.05, the grid's noisy sensor 4.7–7.6 at
    full light, the low-noise one 2.8–3.7. KITTI's noisy cells, Gaussian σ 2 px: ATE 43.9 → 29.0
    mm (noise only), 157 → 62.5 mm (haze); against the renderer's exact depth (haze-row, noisy)
    the median disparity error drops 0.45 → 0.28 px (docs/notes/s10-noise.md).
    """
    if params.subpixel_denoise_sigma <= 0:
        return left_img, right_img, None
    sigma = estimate_noise(left_img, rows_fraction=0.5) if left_sigma is None else left_sigma
    if sigma < params.subpixel_denoise_sigma:
        return left_img, right_img, sigma
    if params.subpixel_denoise_blur > 0:
        blur = lambda img: cv2.GaussianBlur(img, (0, 0), params.subpixel_denoise_blur)  # noqa: E731
    else:
        blur = lambda img: denoise(img, sigma)  # noqa: E731  # the right image with the left's σ
    return blur(left_img), blur(right_img), sigma


def robust_noise_gate(image: np.ndarray, min_robust_sigma: float, noise_sigma: float | None,
                      who: str) -> tuple[float, float | None]:
    """The two noise gates' shared measurement: (the image's robust sigma, its mean sigma), the mean
    (Immerkær, ``track_health.image_noise_sigma``: texture + noise) only when the robust one
    (``estimate_noise``, rows_fraction 0.5, the stereo refinement's estimator: noise alone) reaches
    ``min_robust_sigma``, else None. ``noise_sigma``: the mean sigma when the tracker measured it.
    Their difference is the texture excess both gates test. ``who`` names the caller in the error
    for an image that is not a non-empty 2-D uint8 grey image."""
    img = np.asarray(image) if image is not None else None
    if img is None or img.ndim != 2 or img.dtype != np.uint8 or img.size == 0:
        raise ValueError(f"{who}: image must be a non-empty 2-D uint8 grey image, got "
                         + ("None" if img is None else f"shape {img.shape} dtype {img.dtype}"))
    robust = estimate_noise(img, rows_fraction=0.5)
    if robust < min_robust_sigma:
        return robust, None
    return robust, image_noise_sigma(img) if noise_sigma is None else float(noise_sigma)


class NoiseGatedExtractor:
    """cv2.ORB (``OrbExtractor``) on clean images, ORB-SLAM's per-cell extraction (``CellExtractor``,
    its fallback threshold at ``cell_fallback_noise_factor`` x the noise sigma) on images whose
    Immerkær noise sigma (``track_health.image_noise_sigma``) is at least ``noisy_extractor_sigma``.

    Why (EuRoC, a nearly still camera, docs/notes/s9-jitter.md and s11-noise.md): the pose of a
    still camera jitters by how far its keypoints move from frame to frame times how well their
    layout fixes the translation. cv2.ORB's strongest corners sit on one textured wall patch (84 %
    of them), which fixes the translation 4x less well than corners over the whole image; with a
    noisy sensor the per-cell extraction spreads them, and its fallback threshold at 4 sigma
    (instead of ORB-SLAM's fixed 7 grey levels) keeps the corners that the noise cannot flip: two
    noise draws of one frame give the same corner 59 -> 77 % of the time (tests/test_noisy_fallback.py).
    Frames the enhancement changed (the AFE rule passes ``fallback_threshold``) keep cv2.ORB, as
    ``CellExtractor`` does with ``extractor_enhanced: opencv``. Each image is judged by its own
    sigma (the right image's is ~0.2 below the left's on EuRoC); ``extract`` has the interface of
    both extractors.

    With ``noisy_extractor_robust`` (the generated presets) the gate is the robust sigma and the
    texture excess instead (``_noisy``); the robust sigma it measured is handed on as
    ``Features.robust_noise_sigma`` (the stereo refinement's figure, ``refinement_pair``).
    """

    def __init__(self, params: TrackingParams, responses: bool = True):
        if params.noisy_extractor_sigma <= 0:
            raise ValueError("NoiseGatedExtractor: params.noisy_extractor_sigma must be > 0 "
                             f"(got {params.noisy_extractor_sigma!r})")
        self.params = params
        self.opencv = OrbExtractor(params)
        n = params.noisy_extractor_n_features or params.n_features
        cell_params = replace(params, extractor="cells", n_features=n)
        # per-level FAST floors (s17) on every per-cell image, or with a texture test only on the flat ones
        # (s24: self.level_cells, chosen per image in extract)
        gated = params.noisy_extractor_level_noise and params.noisy_extractor_level_noise_max_texture > 0
        cells = LevelNoiseCellExtractor if params.noisy_extractor_level_noise and not gated else CellExtractor
        self.cells = cells(cell_params, responses)
        self.level_cells = LevelNoiseCellExtractor(cell_params, responses) if gated else None
        self.last_used = ""
        self.last_robust_sigma: float | None = None
        self.last_texture: float | None = None

    def extract(self, image: np.ndarray, fast_threshold: int | None = None,
                fallback_threshold: int | None = None, min_keypoints: int = 0,
                noise_sigma: float | None = None):
        self.last_robust_sigma = None
        if fallback_threshold is None:
            sigma = self._noisy(image, noise_sigma)
            if sigma is not None:
                self.last_used, cells = "cells", self.cells
                if self.level_cells is not None and self.last_texture is not None \
                        and self.last_texture < self.params.noisy_extractor_level_noise_max_texture:
                    # texture under the noise at full resolution: each level's own FAST floor (s24)
                    self.last_used, cells = "level_cells", self.level_cells
                features = cells.extract(image, fast_threshold, None, min_keypoints, noise_sigma=sigma)
                features.robust_noise_sigma = self.last_robust_sigma
                return features
        elif self.params.enhanced_cells_min_corners > 0:
            # an enhanced frame: KITTI's EnhancedCellsRule (canopy.frontend.enhanced_extractor, inside
            # CellExtractor) picks the per-cell extractor with its 4 sigma floor or cv2.ORB (s12-dark)
            self.last_used = "enhanced"
            features = self.cells.extract(image, fast_threshold, fallback_threshold, min_keypoints,
                                          noise_sigma=noise_sigma)
            features.robust_noise_sigma = None
            return features
        self.last_used = "opencv"
        features = self.opencv.extract(image, fast_threshold, fallback_threshold, min_keypoints)
        features.robust_noise_sigma = self.last_robust_sigma
        return features

    def _noisy(self, image: np.ndarray, noise_sigma: float | None) -> float | None:
        """The image's mean (Immerkaer) sigma, the per-cell fallback floor's, if the raw image gets the
        per-cell extraction, else None. ``noise_sigma``: that sigma when the tracker measured it.

        ``noisy_extractor_robust`` (the generated presets, docs/notes/s12-presets.md): the mean sigma
        sees the orchard's fine texture (clean day-loop 4.6-8.9, above the noisy haze-row's 7.0-7.5),
        the robust one barely does (clean presets 0.7-3.1, the grid's noisy sensor 4.9-7.4). And the
        per-cell extraction helps only where the noisy image is flat: cv2.ORB's one FAST threshold (with
        its 3 sigma noise floor) then finds its corners only in the near, textured part of a hazy row,
        where the per-cell extractor spreads them (haze-row's noise-only cell 41.0 -> 33.3 mm, s11-noise);
        on the textured noisy day-loop it loses 2x (6.7 -> 13.0 mm). The texture excess (mean - robust
        sigma, KITTI's ``cell_fallback_noisy_min_texture`` measure) splits them: noisy day-loop 2.4-3.4
        grey levels, noisy and hazy / washed-out rows 0.0-1.7. The robust sigma is measured first, so
        a clean image costs one estimate (the mean one only when the tracker did not measure it)."""
        p = self.params
        self.last_texture = None
        if not p.noisy_extractor_robust:
            sigma = image_noise_sigma(image) if noise_sigma is None else float(noise_sigma)
            return sigma if sigma >= p.noisy_extractor_sigma else None
        robust, sigma = robust_noise_gate(image, p.noisy_extractor_sigma, noise_sigma, "NoiseGatedExtractor.extract")
        self.last_robust_sigma = robust
        if sigma is None:
            return None
        self.last_texture = sigma - robust
        if p.noisy_extractor_max_texture > 0 and sigma - robust >= p.noisy_extractor_max_texture:
            return None
        return sigma


class NoiseGatedCellFallback:
    """ORB-SLAM's per-cell extractor whose fallback factor depends on the image's robust noise sigma:
    ``cell_fallback_noise_factor_noisy`` x sigma on images whose ``estimate_noise`` (rows_fraction
    0.5, the sub-pixel refinement's estimator, ``refinement_pair``) is at least
    ``cell_fallback_noisy_sigma``, ``cell_fallback_noise_factor`` on the others.

    Why two estimators: the fallback floor itself is ``track_health.image_noise_sigma`` (the mean
    |Laplacian difference|), which fine texture raises: clean KITTI measures 2-6 with it, so a 4 sigma
    floor rises on clean frames too (clean KITTI 34.9 -> 39.6 mm, docs/notes/s11-noise.md). The
    robust (median) Immerkær estimate barely sees texture: clean KITTI 1.7-2.0, the grid's low-noise
    sensor 2.8-3.7, the noisy one 5.3-7.6 (docs/notes/s10-noise.md). So the robust sigma decides
    *whether* the image is noisy, and the 4 sigma floor of ``image_noise_sigma`` (what the fallback
    corners must stand above, s11-noise on EuRoC) is applied only then: a clean image gets exactly
    the ungated extractor's features. Frames the enhancement changed (``fallback_threshold`` given)
    go to the ungated extractor as before. Each image is judged by its own sigma.

    Not on hazy images (``cell_fallback_noisy_min_texture``): with sigma 3-9 the 4 sigma floor is
    above the FAST threshold itself, so the noisy images get no fallback corners at all; a hazy
    image needs them in its washed-out far half. Haze flattens the texture, and the mean |Laplacian|
    (``image_noise_sigma``) sees texture + noise where the median (the robust sigma) sees the noise,
    so their difference, the texture excess in grey levels, separates them on KITTI (left and right
    images, all frames): clean 3.4-4.5, low-noise sensor 3.0-4.1, noisy 2.4-3.5 (seeds 0-2), haze
    0.03 + low-noise 1.3-1.9, haze 0.03 / 0.06 + either sensor 0.2-1.3 (seeds 0-1). Their ratio does
    not (noisy 1.45-1.64, haze 0.03 + low-noise 1.36-1.55: the 1.35 ratio gate cost that cell
    42.3 -> 55.7 mm). Without any test: haze 0.06 + noisy sensor 62.5 -> 202 mm, + low-noise 66.4 ->
    88.2 mm (docs/notes/s11-noise.md).
    """

    def __init__(self, params: TrackingParams, responses: bool = True):
        if params.extractor != "cells" or params.cell_fallback_noisy_sigma <= 0:
            raise ValueError("NoiseGatedCellFallback: params.extractor must be 'cells' and "
                             f"params.cell_fallback_noisy_sigma > 0 (got {params.extractor!r}, "
                             f"{params.cell_fallback_noisy_sigma!r})")
        self.params = params
        self.clean = CellExtractor(params, responses)
        self.noisy = CellExtractor(replace(params, cell_fallback_noise_factor=params.cell_fallback_noise_factor_noisy),
                                   responses)
        self.last_used = ""
        self.last_robust_sigma: float | None = None

    def extract(self, image: np.ndarray, fast_threshold: int | None = None,
                fallback_threshold: int | None = None, min_keypoints: int = 0,
                noise_sigma: float | None = None):
        ext = self.clean
        self.last_robust_sigma = None
        if fallback_threshold is None:
            robust, sigma = robust_noise_gate(image, self.params.cell_fallback_noisy_sigma, noise_sigma,
                                              "NoiseGatedCellFallback.extract")
            self.last_robust_sigma = robust
            if sigma is not None:
                noise_sigma = sigma  # the fallback floor's sigma, measured once for both tests
                if sigma - robust >= self.params.cell_fallback_noisy_min_texture:
                    ext = self.noisy
        self.last_used = "noisy" if ext is self.noisy else "clean"
        features = ext.extract(image, fast_threshold, fallback_threshold, min_keypoints, noise_sigma=noise_sigma)
        features.robust_noise_sigma = self.last_robust_sigma
        return features


def tracking_extractor(params: TrackingParams, responses: bool = True):
    """The tracker's extractor: ``NoiseGatedExtractor`` when ``noisy_extractor_sigma`` > 0 and
    ``extractor`` is opencv, ``NoiseGatedCellFallback`` when ``cell_fallback_noisy_sigma`` > 0 and
    ``extractor`` is cells, else the one ``params.extractor`` names."""
    if params.noisy_extractor_sigma > 0 and params.extractor == "opencv":
        return NoiseGatedExtractor(params, responses)
    if params.cell_fallback_noisy_sigma > 0 and params.extractor == "cells":
        return NoiseGatedCellFallback(params, responses)
    return make_extractor(params, responses)
