"""How well the image pins a stereo match's disparity (issue 9: haze + a noisy sensor), and the
landmarks that should not be made from it.

Haze scales a patch's contrast by the transmission t (Koschmieder, I = J·t + A·(1 − t)) and the sensor
adds a fixed noise σ_n, so the SAD search of a far hazy corner compares windows whose gradients sit a
few σ_n above the noise: its disparity scatters by pixels, and the depth of a landmark made from it by
tens of percent. ORB-SLAM trusts stereo depth by distance alone (ThDepth); the image says more.

The bound is the Cramér-Rao / Förstner one for aligning a window of known appearance in white noise
(Förstner & Gülch 1987; Kanazawa & Kanatani, "Do we really have to consider covariance matrices for
image features?", ICCV 2001): with M = Σ_window ∇I ∇Iᵀ (the structure tensor), Σ_shift = σ_n² M⁻¹.
The stereo search moves the window along the row only, so the disparity's bound is the 1-D one,
σ_d² = 2 σ_n² / Σ gx² (both images carry the noise), with the tensor's own noise part removed first:
each central difference of white noise has variance σ_n² / 2, so E[Σ gx²] = Σ gx²_signal + n σ_n² / 2
over n window pixels. The window is sampled on level 0 at the keypoint's scale (a (2h+3)² grid at
spacing s^o, bilinear), standing in for the level-o image the SAD ran on.

σ_d / d is the relative depth sigma of the point (z = b f / d). ``TrackerMeasurementsMixin`` withholds
landmarks from points where it is large (``tracking.uncertain_stereo_*``, docs/notes/s16-darkhaze.md).
"""
from __future__ import annotations

import cv2
import numpy as np


def row_gradient_energy(image: np.ndarray, uv: np.ndarray, spacing: np.ndarray,
                        half_window: int) -> tuple[np.ndarray, int]:
    """Σ gx² over a (2h+1)² window of central differences along the row around each keypoint, sampled
    on ``image`` at ``spacing`` (level-0 px per sample; the keypoint's scale) by bilinear interpolation;
    gradients per sample step. Returns (Σ gx², n_pixels)."""
    k = len(uv)
    h = int(half_window)
    n = (2 * h + 1) ** 2
    if k == 0:
        return np.zeros(0), n
    cols = np.arange(-(h + 1), h + 2, dtype=np.float32)  # one more sample each side for the differences
    rows = np.arange(-h, h + 1, dtype=np.float32)
    s = spacing.astype(np.float32)[:, None, None]
    map_x = np.broadcast_to(uv[:, 0].astype(np.float32)[:, None, None] + s * cols[None, None, :], (k, len(rows), len(cols)))
    map_y = np.broadcast_to(uv[:, 1].astype(np.float32)[:, None, None] + s * rows[None, :, None], (k, len(rows), len(cols)))
    patches = cv2.remap(image.astype(np.float32) if image.dtype != np.float32 else image,
                        np.ascontiguousarray(map_x).reshape(-1, len(cols)), np.ascontiguousarray(map_y).reshape(-1, len(cols)),
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101).reshape(k, len(rows), len(cols))
    gx = 0.5 * (patches[:, :, 2:] - patches[:, :, :-2])
    return np.einsum("kij,kij->k", gx, gx), n


def sampled_noise_factors(uv: np.ndarray, spacing: np.ndarray, half_window: int) -> tuple[np.ndarray, np.ndarray]:
    """White noise of variance σ² as ``row_gradient_energy`` samples it, per keypoint: (e, c) with
    E[Σ gx²_noise] = e σ² and c σ² the mean variance of a sample.

    A bilinear sample at fractional offsets (fx, fy) is Σ w I over four pixels, so its noise variance is
    σ² Σ w² = σ² ((1 − fx)² + fx²)((1 − fy)² + fy²): 1 on the pixel grid (octave 0, whose keypoints
    sit on integer pixels), 4/9 on average over the phases of a window sampled at spacing 1.2^o (the
    level-o image the SAD runs on is a bilinear resize: the same averaging). The two samples of a
    central difference are ≥ 2 px apart (spacing ≥ 1) and share no pixel, so each gx carries
    (v_{j−1} + v_{j+1}) σ² / 4. White-noise arithmetic (n σ² / 2 for the energy, σ² per sample) is the
    octave-0 case; on KITTI g1-b0.06-high the measured noise energy of the window (two noise draws of
    the same cell) is 1.00 / 0.46 / 0.44 ... of n σ² / 2 at octaves 0 / 1 / 2 ..., this function's
    figures to 2 % (docs/notes/s17-kittihaze.md)."""
    h = int(half_window)
    k = len(uv)
    if k == 0:
        return np.zeros(0), np.zeros(0)
    cols = np.arange(-(h + 1), h + 2, dtype=np.float64)
    rows = np.arange(-h, h + 1, dtype=np.float64)
    s = spacing.astype(np.float64)[:, None]
    fx = np.mod(uv[:, 0].astype(np.float64)[:, None] + s * cols[None, :], 1.0)
    fy = np.mod(uv[:, 1].astype(np.float64)[:, None] + s * rows[None, :], 1.0)
    vx = (1.0 - fx) ** 2 + fx ** 2  # per-sample variance factor along the row (k, 2h + 3)
    vy = (1.0 - fy) ** 2 + fy ** 2  # ... along the column (k, 2h + 1)
    energy = 0.25 * vy.sum(axis=1) * (vx[:, 2:] + vx[:, :-2]).sum(axis=1)
    mean_var = vy.mean(axis=1) * vx[:, 1:-1].mean(axis=1)
    return energy, mean_var


def disparity_sigma(image: np.ndarray, uv: np.ndarray, octave: np.ndarray, scale_factors: np.ndarray,
                    noise_sigma: float, half_window: int, sampled_noise: bool = False) -> np.ndarray:
    """Cramér-Rao sigma of a stereo match's disparity (level-0 px; inf where the window's x-gradients
    are noise only): the SAD search aligns a (2h+1)² window along the row only, so the bound is the
    1-D one, σ_d² = 2 σ_n² / Σ gx²_signal (both images carry the noise, hence the 2; Σ gx²'s noise part
    n σ_n² / 2 removed: module doc), scaled by s^o to level 0. On KITTI 06 with haze
    β 0.06 and the noisy sensor the top tenth of this sigma relative to the disparity (≥ 0.036) holds
    the stereo points with twice the error against the clean pair's SGBM (|Δd| p50 0.89 px, 46 % over
    1 px, against 0.44 px and 21 % in the lowest fifth; docs/notes/s16-darkhaze.md).

    ``sampled_noise``: the noise as the resampled window carries it (``sampled_noise_factors``: the
    energy e σ² removed, c σ² per sample in the numerator) instead of white-noise arithmetic, which
    over-counts the noise 2.2 × at octaves ≥ 1 (where the signal then often comes out ≤ 0: an infinite
    bound for a point whose window holds 1.2 × the noise's energy)."""
    spacing = scale_factors[octave]
    sxx, n = row_gradient_energy(image, uv, spacing, half_window)
    if sampled_noise:
        energy, per_sample = sampled_noise_factors(uv, spacing, half_window)
        signal = sxx - energy * noise_sigma**2
        numerator = 2.0 * per_sample * noise_sigma**2
    else:
        signal = sxx - n * noise_sigma**2 / 2.0
        numerator = 2.0 * noise_sigma**2
    with np.errstate(divide="ignore", invalid="ignore"):
        sd = np.where(signal > 0, np.sqrt(numerator / np.maximum(signal, 1e-12)), np.inf)
    return sd * spacing
