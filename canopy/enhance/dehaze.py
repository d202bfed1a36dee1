"""AGRI-SLAM §3.1: low-light enhancement by dehazing the inverted image (Eq. 1–5).

The dark channel prior core (He et al.; AGRI Eq. 2–4) is shared by two methods:
``dehaze_inverted`` (``agri``: invert, dehaze, invert back) and
``dehaze_dark_channel`` (the same dehazing on the image itself, used by
``auto`` for hazy frames).

Atmospheric light. AGRI: "A has been calculated by selecting 200 pixels with
the lowest intensities in all colour channels. Among them, a single pixel has
been chosen to have the highest value for the sum of all channels." This is a
rewording of Dong et al. 2011 (the paper AGRI cites for the method), who pick,
*in the inverted image*, the pixels whose minimum over the colour channels is
highest, then the one with the largest channel sum. Read on the inverted image
Q literally ("lowest intensities" of Q) it would pick A ≈ 0 and Eq. 3–4 would
blow up, so "lowest intensities" is about the low-light input P, i.e. the
brightest pixels of Q's dark channel. We therefore rank pixels by the dark
channel of the image being dehazed (min over channels and the Ω block, as
He et al. do), take the ``n_dark_pixels`` highest (= the darkest of P), and
among them the pixel with the largest channel sum of Q (= smallest sum of P);
A is that pixel's value in Q. Ties at the 200th value are all kept (the
candidate set is every pixel whose dark value is ≥ the 200th highest), so the
choice does not depend on scan order; among equal sums the first pixel in
raster order wins. A is floored at 1 grey level so Q/A stays finite.

Speed (grey, the EuRoC/KITTI case). With one channel Eq. 3 depends on the
pixel only through its dark-channel value d, and J only through (d, Q),
so Eq. 4 is tabulated per frame as a 256×256 uint8 table J[d, Q] (64 KiB,
stays in cache) and applied with one gather — no full-size float temporaries
(those cost 4–11 ms here, mostly allocation).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.enhance.common import check_image
from canopy.enhance.params import EnhanceParams


def _kernel(block: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_RECT, (block, block))


def dark_channel(image: np.ndarray, block: int) -> np.ndarray:
    """min over colour channels and a block×block window (Eq. 3's double min, without /A).

    cv2.erode's default border ignores pixels outside the image, so the
    window is clipped at the borders.
    """
    if image.ndim == 2:
        per_pixel = image
    else:
        b, g, r = cv2.split(image)
        per_pixel = cv2.min(cv2.min(b, g), r)
    return cv2.erode(per_pixel, _kernel(block))


def atmospheric_light(image: np.ndarray, dark: np.ndarray, n_pixels: int) -> np.ndarray:
    """A per channel (float64, shape (C,)), chosen as described in the module docstring."""
    hist = np.bincount(dark.ravel(), minlength=256) if dark.size < 4096 else \
        cv2.calcHist([dark], [0], None, [256], [0, 256]).ravel()
    at_least = np.cumsum(hist[::-1])[::-1]          # pixels with dark value >= v
    n = min(n_pixels, dark.size)
    v_star = int(np.nonzero(at_least >= n)[0].max())  # the n-th highest dark value
    mask = (dark >= v_star).astype(np.uint8)
    if image.ndim == 2:
        _, a_max, _, _ = cv2.minMaxLoc(image, mask)
        a = np.array([a_max], dtype=np.float64)
    else:
        candidates = np.flatnonzero(mask)
        flat = image.reshape(-1, 3)[candidates].astype(np.int32)
        a = flat[int(np.argmax(flat.sum(axis=1)))].astype(np.float64)
    return np.maximum(a, 1.0)


def _dehaze(image: np.ndarray, params: EnhanceParams) -> np.ndarray:
    """Dark channel prior dehazing of ``image`` (AGRI Eq. 2–4); uint8 J, clipped to [0, 255]."""
    dark = dark_channel(image, params.block)
    a = atmospheric_light(image, dark, params.n_dark_pixels)
    if image.ndim == 2:
        # Eq. 3 on one channel: t(d) = 1 - ω d / A, clamped to [t0, 1].
        levels = np.arange(256, dtype=np.float64)
        t = np.clip(1.0 - params.omega * levels / a[0], params.t0, 1.0)   # t[d]
        # Eq. 4: J = (Q - A)/t + A, tabulated as J[d, Q], rounded and clipped.
        table = (levels[None, :] - a[0]) / t[:, None] + a[0]
        table = np.clip(np.rint(table), 0, 255).astype(np.uint8).ravel()
        index = (dark.astype(np.uint16) << 8) | image
        return table.take(index)
    # Colour: Eq. 3 with per-channel A, min over Ω per channel then over channels.
    block_min = cv2.split(cv2.erode(image, _kernel(params.block)))
    ratio = cv2.min(cv2.min(block_min[0] * np.float32(1.0 / a[0]), block_min[1] * np.float32(1.0 / a[1])),
                    block_min[2] * np.float32(1.0 / a[2]))
    t = np.clip(1.0 - np.float32(params.omega) * ratio, np.float32(params.t0), np.float32(1.0))
    # numpy, not cv2.divide(1.0, t): OpenCV's Python binding turns the scalar into a 4x1 Scalar and
    # mistakes a 1x1 t for the scalar (5.1: a 4x1 result) or rejects a 4x1 t (5.0); t >= t0 > 0,
    # the same float32 quotients, and faster than cv2.divide on 5.0
    inv_t = np.float32(1.0) / t
    # Eq. 4 per channel: J = (Q - A)/t + A = Q·(1/t) + A·(1 - 1/t)
    channels = [cv2.add(cv2.multiply(c.astype(np.float32), inv_t), np.float32(a_c) * (1.0 - inv_t),
                        dtype=cv2.CV_8U)
                for c, a_c in zip(cv2.split(image), a)]
    return cv2.merge(channels)


def dehaze_inverted(image: np.ndarray, params: EnhanceParams | None = None) -> np.ndarray:
    """AGRI low-light enhancement: invert (Eq. 1), dehaze (Eq. 2–4), invert back (Eq. 5)."""
    image = check_image(image)
    params = params or EnhanceParams()
    q = cv2.bitwise_not(image)                    # Eq. 1: Q = 255 - P
    return cv2.bitwise_not(_dehaze(q, params))    # Eq. 5: I = 255 - J


def dehaze_dark_channel(image: np.ndarray, params: EnhanceParams | None = None) -> np.ndarray:
    """Dark channel prior dehazing of a hazy image itself (Eq. 2–4 applied to P, no inversion)."""
    image = check_image(image)
    return _dehaze(image, params or EnhanceParams())
