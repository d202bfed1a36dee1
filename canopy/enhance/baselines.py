"""Baselines of AFE §5.4 (HE-SLAM, CLAHE-SLAM) and the identity."""
from __future__ import annotations

import cv2
import numpy as np

from canopy.enhance.common import check_image, on_luma
from canopy.enhance.params import EnhanceParams


def none(image: np.ndarray, params: EnhanceParams | None = None) -> np.ndarray:
    """Identity: returns the input object itself (checked, not copied)."""
    return check_image(image)


def histogram_equalise(image: np.ndarray, params: EnhanceParams | None = None) -> np.ndarray:
    """Global histogram equalisation (cv2.equalizeHist); colour on the Y channel."""
    return on_luma(check_image(image), cv2.equalizeHist)


def clahe(image: np.ndarray, params: EnhanceParams | None = None) -> np.ndarray:
    """Contrast-limited adaptive HE (cv2.createCLAHE); colour on the Y channel."""
    params = params or EnhanceParams()
    op = cv2.createCLAHE(clipLimit=params.clahe_clip,
                         tileGridSize=(params.clahe_tiles, params.clahe_tiles))
    return on_luma(check_image(image), op.apply)
