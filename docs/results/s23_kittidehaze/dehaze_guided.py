"""(Scratch for docs/notes/s23-kittidehaze.md, not part of the package.) Dark channel prior dehazing with an edge-following transmission (He, Sun, Tang 2010/2013).

``dehaze.py``'s dehazing (AGRI Eq. 2–4) takes the transmission straight from the dark channel over
a 9×9 block Ω. Across a depth edge that block's minimum belongs to the near (darker, less hazy)
side, so the far side of every silhouette gets the near side's t: a halo whose far surface keeps its
haze — exactly the patches whose stereo matches haze biases toward the near disparity
(docs/notes/s22-hazepaint.md). Here the raw transmission t̃ = 1 − ω·dark/A is refined by a guided
filter with the hazy grey image as the guide (He et al. 2013, "Guided image filtering", Eq. 2–8 and
§4.4 "dehazing"), so t follows the image's edges; J = (I − A)/max(t, t0) + A (He et al. 2011, Eq. 22;
AGRI Eq. 4). The lower bound t0 bounds the noise gain 1/t.

Speed: the dark channel, A and the guided filter's coefficients are computed on a copy downsampled
by ``downsample`` (INTER_AREA; a 3×3 minimum there is a ~12×12 block at full scale), the coefficients
are upsampled and applied at full resolution (He & Sun 2015, "Fast guided filter"); the removal is
tabulated as J[t8, I] (256×256 uint8, t quantised to 1/255) and applied with one gather, as in
``dehaze.py``.

Grey images only (KITTI, EuRoC); a colour image is dehazed on its luma.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.enhance.common import check_image, on_luma


def _small(grey: np.ndarray, f: int) -> np.ndarray:
    h, w = grey.shape
    if f <= 1 or h < f or w < f:
        return grey
    return cv2.resize(grey[: h - h % f, : w - w % f], (w // f, h // f), interpolation=cv2.INTER_AREA)


def airlight_from_dark(grey_small: np.ndarray, dark_small: np.ndarray, n_pixels: int) -> float:
    """A: the mean grey of the ``n_pixels`` pixels with the highest dark channel (He et al. take the
    brightest of them; with sensor noise the brightest is A + 2–3σ, the mean is not)."""
    n = max(1, min(int(n_pixels), dark_small.size))
    idx = np.argpartition(dark_small.ravel(), dark_small.size - n)[-n:]
    return max(1.0, float(grey_small.ravel()[idx].mean()))


def guided_transmission(grey: np.ndarray, airlight: float, omega: float, radius: int, eps: float,
                        downsample: int = 4) -> np.ndarray:
    """t (float32, full size, unclamped) of a grey uint8 image: 1 − ω·dark/A at 1/``downsample``
    scale (dark = 3×3 minimum there), refined by the guided filter (guide = the grey image in [0, 1],
    window radius ``radius`` px at full scale, regulariser ``eps``), coefficients upsampled."""
    f = max(1, int(downsample))
    small = _small(grey, f)
    dark = cv2.erode(small, cv2.getStructuringElement(cv2.MORPH_RECT, (3, 3)))
    t_raw = 1.0 - np.float32(omega / airlight) * dark.astype(np.float32)
    g = small.astype(np.float32) * np.float32(1.0 / 255.0)
    r = max(1, int(round(radius / f)))
    box = (2 * r + 1, 2 * r + 1)
    mean_g = cv2.boxFilter(g, -1, box)
    mean_t = cv2.boxFilter(t_raw, -1, box)
    cov = cv2.boxFilter(g * t_raw, -1, box) - mean_g * mean_t
    var = cv2.boxFilter(g * g, -1, box) - mean_g * mean_g
    a = cov / (var + np.float32(eps))                     # He 2013 Eq. 5
    b = mean_t - a * mean_g                               # Eq. 6
    a = cv2.boxFilter(a, -1, box)                         # Eq. 8: mean over the windows
    b = cv2.boxFilter(b, -1, box)
    h, w = grey.shape
    a = cv2.resize(a, (w, h), interpolation=cv2.INTER_LINEAR)
    b = cv2.resize(b, (w, h), interpolation=cv2.INTER_LINEAR)
    return a * (grey.astype(np.float32) * np.float32(1.0 / 255.0)) + b


def remove_haze(grey: np.ndarray, t: np.ndarray, airlight: float, t0: float) -> np.ndarray:
    """J = (I − A)/max(t, t0) + A, rounded and clipped to uint8, via a J[t8, I] table."""
    t8 = np.clip(np.rint(t * 255.0), 0, 255).astype(np.uint16)
    levels = np.arange(256, dtype=np.float64)
    tt = np.clip(levels / 255.0, t0, 1.0)
    table = (levels[None, :] - airlight) / tt[:, None] + airlight
    table = np.clip(np.rint(table), 0, 255).astype(np.uint8).ravel()
    return table.take((t8 << 8) | grey)


def dehaze_guided_airlight(image: np.ndarray, params) -> float:
    """A of ``image`` as ``dehaze_guided`` estimates it (the right image of a pair gets the left's)."""
    image = check_image(image)
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    small = _small(grey, params.auto_downsample)
    dark = cv2.erode(small, cv2.getStructuringElement(cv2.MORPH_RECT, (3, 3)))
    return airlight_from_dark(small, dark, params.n_dark_pixels)


def dehaze_guided(image: np.ndarray, params, airlight: float | None = None) -> np.ndarray:
    """Dehaze with the guided transmission; ``airlight`` None = estimate A from ``image``."""
    image = check_image(image)
    a = dehaze_guided_airlight(image, params) if airlight is None else float(airlight)

    def grey_fn(grey):
        t = guided_transmission(grey, a, params.guided_omega, params.guided_radius, params.guided_eps,
                                params.auto_downsample)
        return remove_haze(grey, t, a, params.guided_t0)
    return on_luma(image, grey_fn)
