"""Input checks and luma helpers shared by the enhancement methods."""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from shared.errors import InputError


def check_image(image, name: str = "image") -> np.ndarray:
    """Return ``image`` as a C-contiguous uint8 (H, W) or (H, W, 3) array, or raise InputError."""
    if not isinstance(image, np.ndarray):
        raise InputError(name, f"expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise InputError(name, f"expected dtype uint8, got {image.dtype}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise InputError(name, f"expected shape (H, W) or (H, W, 3), got {image.shape}")
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise InputError(name, f"empty image of shape {image.shape}")
    return np.ascontiguousarray(image)


def on_luma(image: np.ndarray, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Apply a grey-level ``fn`` to a grey image, or to the Y channel of a BGR image."""
    if image.ndim == 2:
        return fn(image)
    ycrcb = cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb)
    ycrcb[:, :, 0] = fn(np.ascontiguousarray(ycrcb[:, :, 0]))
    return cv2.cvtColor(ycrcb, cv2.COLOR_YCrCb2BGR)


def luma(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def mean_std(image: np.ndarray) -> tuple[float, float]:
    """Mean and standard deviation of the grey level (luma for colour)."""
    m, s = cv2.meanStdDev(luma(image))
    return float(m[0, 0]), float(s[0, 0])
