"""ORB extraction with grid bucketing (AGRI §3.2.1; spread as in ORB-SLAM's ORBextractor).

OpenCV's ORB keeps the strongest Harris responses per pyramid level, which clusters
features on high-contrast areas. We ask for ``oversample * n_features`` corners and keep
the strongest ones cell by cell (equal quota per cell, leftovers to the globally
strongest), so tracking keeps constraints all over the image.
"""
from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter

import cv2
import numpy as np

from canopy.frontend.params import TrackingParams

_OCTAVE, _RESPONSE = attrgetter("octave"), attrgetter("response")


@dataclass
class Features:
    """Keypoints of one image as arrays (row i = keypoint i)."""

    uv: np.ndarray           # (N,2) float32 pixel coordinates at level 0
    octave: np.ndarray       # (N,) int32 pyramid level
    response: np.ndarray     # (N,) float32
    descriptors: np.ndarray  # (N,32) uint8
    # which extractor found them ("opencv" | "cells"): the stereo disparity offset depends on it
    extractor: str = "opencv"
    # the image's robust noise sigma (canopy.enhance.noise.estimate_noise, rows_fraction 0.5) when the
    # extractor measured it (noisy_features.NoiseGatedCellFallback): the stereo refinement's pair
    # choice needs the same figure of the left image and reuses it instead of measuring again
    robust_noise_sigma: float | None = None

    def __len__(self) -> int:
        return len(self.uv)

    @staticmethod
    def empty() -> "Features":
        return Features(np.zeros((0, 2), np.float32), np.zeros(0, np.int32),
                        np.zeros(0, np.float32), np.zeros((0, 32), np.uint8))

    def subset(self, idx: np.ndarray) -> "Features":
        return Features(self.uv[idx], self.octave[idx], self.response[idx], self.descriptors[idx], self.extractor,
                        self.robust_noise_sigma)


def grid_select(uv: np.ndarray, response: np.ndarray, width: int, height: int,
                n_keep: int, cols: int, rows: int) -> np.ndarray:
    """Indices of at most ``n_keep`` keypoints, an equal quota per grid cell first."""
    n = len(uv)
    if n <= n_keep:
        return np.arange(n)
    cx = np.clip((uv[:, 0] * cols / width).astype(np.int64), 0, cols - 1)
    cy = np.clip((uv[:, 1] * rows / height).astype(np.int64), 0, rows - 1)
    cell = cy * cols + cx
    # by cell, strongest first within a cell (one argsort on a combined key; responses are
    # replaced by their rank so the key stays an exact integer)
    rank_resp = np.empty(n, np.int64)
    rank_resp[np.argsort(-response, kind="stable")] = np.arange(n)
    order = np.argsort(cell * n + rank_resp)
    cs = cell[order]
    first = np.ones(n, bool)
    first[1:] = cs[1:] != cs[:-1]
    group_start = np.maximum.accumulate(np.where(first, np.arange(n), 0))
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n) - group_start
    quota = max(1, n_keep // (cols * rows))
    chosen = rank < quota
    n_chosen = int(chosen.sum())
    if n_chosen > n_keep:  # more cells than quota allows: strongest of the chosen
        idx = np.flatnonzero(chosen)
        idx = idx[np.argsort(-response[idx], kind="stable")[:n_keep]]
        return np.sort(idx)
    rest = np.flatnonzero(~chosen)
    rest = rest[np.argsort(-response[rest], kind="stable")[: n_keep - n_chosen]]
    return np.sort(np.concatenate([np.flatnonzero(chosen), rest]))


class OrbExtractor:
    """ORB on one image; ``extract(image, fast_threshold=None)``.

    ``fast_threshold`` overrides the configured FAST threshold for this call (the
    adaptive FAST threshold of AFE-ORB-SLAM Eq. 18-19 plugs in here).
    """

    def __init__(self, params: TrackingParams):
        self.params = params
        self._orb = cv2.ORB_create(
            nfeatures=int(round(params.n_features * params.oversample)),
            scaleFactor=params.scale_factor,
            nlevels=params.n_levels,
            edgeThreshold=params.edge_threshold,
            firstLevel=0,
            WTA_K=2,
            scoreType=cv2.ORB_HARRIS_SCORE,
            patchSize=params.patch_size,
            fastThreshold=params.fast_threshold,
        )
        self.scale_factors = params.scale_factor ** np.arange(params.n_levels)

    def extract(self, image: np.ndarray, fast_threshold: int | None = None,
                fallback_threshold: int | None = None, min_keypoints: int = 0,
                noise_sigma: float | None = None) -> Features:
        """``fallback_threshold``: AFE Eq. 19, retried when ``fast_threshold``
        (Eq. 18) yields fewer than ``min_keypoints`` corners. ``noise_sigma`` is unused (the
        ``CellExtractor`` interface: cv2.ORB has no noise floor of its own)."""
        thr = self.params.fast_threshold if fast_threshold is None else int(fast_threshold)
        self._orb.setFastThreshold(thr)
        kps, desc = self._orb.detectAndCompute(image, None)
        if fallback_threshold is not None and len(kps) < min_keypoints and int(fallback_threshold) < thr:
            self._orb.setFastThreshold(int(fallback_threshold))
            kps, desc = self._orb.detectAndCompute(image, None)
        if desc is None or len(kps) == 0:
            return Features.empty()
        uv = cv2.KeyPoint_convert(kps).astype(np.float32).reshape(-1, 2)
        # one attribute getter per field straight into its dtype (no Python frame per keypoint)
        octave = np.fromiter(map(_OCTAVE, kps), np.int32, len(kps))
        response = np.fromiter(map(_RESPONSE, kps), np.float32, len(kps))
        h, w = image.shape[:2]
        keep = grid_select(uv, response, w, h, self.params.n_features,
                           self.params.grid_cols, self.params.grid_rows)
        return Features(uv[keep], octave[keep], response[keep], desc[keep])
