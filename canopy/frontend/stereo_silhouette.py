"""Stereo keypoints on occluding contours (silhouettes): depth that belongs to no 3D point.

An ORB corner on the rim of a trunk or crown is formed by the foreground edge *and* the
background behind it. The two cameras see different background behind the rim (that is what
an occlusion is), so the left corner and the right "corner" are not images of one 3D point: a
T-junction, not a point. Its stereo disparity mixes foreground and background (the 11x11 SAD
window straddles the depth step), and as the camera moves the junction slides along the rim.
Used as a stereo measurement it pulls the pose (docs/notes/s4-drift.md: the day-loop's pitch
drift at the row ends, where 40-80 % of the landmark candidates sit on crown silhouettes).

The test here: one dense block-matching disparity map per frame (``cv2.StereoBM``, on a
downscaled copy: it only has to say *where* the depth steps are, not how deep), then a
keypoint is on a contour when the dense disparity within ``window_px`` of it varies by more
than ``ratio`` (max > (1 + ratio) min over the neighbourhood: a grey-scale dilation and
erosion of the map, looked up at the keypoints), or when block matching found no disparity
there (no match = occluded or sky: background). ORB-SLAM's answer to points whose stereo
depth cannot be trusted (far points beyond ThDepth, Mur-Artal & Tardós 2017, §III-A) is to use
them as monocular observations; the tracker does the same with these
(``canopy.frontend.tracker_measurements``).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from shared.errors import ConfigError

_BM_INVALID = 0.0  # disparity written where block matching found no match: "background"


@dataclass(frozen=True)
class ContourParams:
    """How the dense disparity is computed and when a keypoint counts as on a contour."""

    window_px: float = 3.0          # neighbourhood radius, level-0 px
    ratio: float = 0.10             # max / min disparity over the neighbourhood above 1 + ratio
    downscale: int = 2              # the dense match runs on the image shrunk by this factor
    max_disparity_px: float = 64.0  # level-0 px; block matching searches up to this (rounded up to 16s)
    block_size: int = 7             # StereoBM window at the downscaled resolution (odd, >= 5)
    octave_scaled: bool = False     # window_px times scale^octave for pyramid-level keypoints
    # Frame gate: the test's "unmatched = background" rule only holds where block matching works.
    # On dark or noisy enhanced frames StereoBM's uniqueness / texture checks reject most of the
    # image (haze-row at 6 % light: 45 % of it matched, 83 % of the stereo keypoints flagged, 71 %
    # for "unmatched near"; docs/notes/s11-drift.md), so the frame's flags say nothing about
    # silhouettes. Below this matched fraction of the searchable image no keypoint is flagged.
    min_matched_fraction: float = 0.0
    # False: a keypoint with no block-matching disparity near it is not flagged (only disparity steps
    # are contours); True: unmatched counts as background (the rule above).
    unmatched_is_contour: bool = True
    # > 0 (with unmatched_is_contour): only unmatched regions that survive a morphological opening
    # with a disc of this radius (downscaled px; sky, wide occlusions) count as background; smaller
    # holes (block matching failing on a low-texture patch of a row's foliage) do not.
    unmatched_min_radius: int = 0
    # Frame cap: no keypoint is flagged either when more than this fraction of the tested
    # keypoints would be (1: no cap; the rows flag 22-58 % per frame, so no cap was used).
    max_flagged_fraction: float = 1.0

    def validate(self) -> "ContourParams":
        def need(ok: bool, name: str, what: str) -> None:
            if not ok:
                raise ConfigError("ContourParams", f"{name} {what} (got {getattr(self, name)!r})")

        need(self.window_px >= 1.0, "window_px", "must be >= 1 px")
        need(self.ratio > 0.0, "ratio", "must be > 0")
        need(self.downscale in (1, 2, 4), "downscale", "must be 1, 2 or 4")
        need(self.max_disparity_px > 0, "max_disparity_px", "must be > 0")
        need(self.block_size >= 5 and self.block_size % 2 == 1, "block_size", "must be odd and >= 5")
        need(0.0 <= self.min_matched_fraction <= 1.0, "min_matched_fraction", "must be in [0, 1]")
        need(self.unmatched_min_radius >= 0, "unmatched_min_radius", "must be >= 0")
        need(0.0 < self.max_flagged_fraction <= 1.0, "max_flagged_fraction", "must be in (0, 1]")
        return self

    @classmethod
    def from_tracking(cls, p) -> "ContourParams":
        """The ``tracking.contour_*`` settings of a ``TrackingParams``."""
        return cls(window_px=p.contour_window_px, ratio=p.contour_ratio, downscale=p.contour_downscale,
                   max_disparity_px=p.contour_max_disparity_px, octave_scaled=p.contour_octave_scaled,
                   min_matched_fraction=p.contour_min_matched_fraction,
                   max_flagged_fraction=p.contour_max_flagged_fraction,
                   unmatched_is_contour=p.contour_unmatched_is_contour,
                   unmatched_min_radius=p.contour_unmatched_min_radius)


class SilhouetteDetector:
    """Dense disparity once per frame, contour flags at the stereo keypoints (module docstring).

    One instance per tracker (it keeps its ``cv2.StereoBM`` object, which is not thread-safe).
    """

    def __init__(self, params: ContourParams):
        self.params = params.validate()
        # StereoBM searches [0, numDisparities) at the downscaled resolution, a multiple of 16
        self.num_disparities = 16 * max(1, int(np.ceil(params.max_disparity_px / params.downscale / 16.0)))
        self._bm = cv2.StereoBM_create(numDisparities=self.num_disparities, blockSize=params.block_size)
        self.radius = int(np.ceil(params.window_px / params.downscale))
        self._kernels: dict[int, np.ndarray] = {}

    def disparity(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, int]:
        """Dense disparity (float32, downscaled px; ``_BM_INVALID`` where unmatched) and the
        first column block matching can search (left of it every disparity is cut off)."""
        for name, img in (("left", left), ("right", right)):
            if img.ndim != 2 or img.dtype != np.uint8:
                raise ValueError(f"silhouette test needs 8-bit grey stereo images; {name} image is "
                                 f"{img.dtype} with shape {img.shape}")
        if left.shape != right.shape:
            raise ValueError(f"left image {left.shape} and right image {right.shape} differ in size")
        s = self.params.downscale
        if s > 1:
            size = (left.shape[1] // s, left.shape[0] // s)
            left = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
            right = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
        d = self._bm.compute(left, right).astype(np.float32) * (1.0 / 16.0)  # fixed point, 4 bits
        d[d <= 0] = _BM_INVALID  # -1 (no match) and 0 (no measurable parallax) alike: background
        return d, self.num_disparities + self.params.block_size // 2

    def _min_max(self, disparity: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Max and min of the disparity over the disc of radius ``r`` around every pixel at once
        (grey-scale dilation and erosion)."""
        k = self._kernels.get(r)
        if k is None:
            k = self._kernels[r] = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        return cv2.dilate(disparity, k), cv2.erode(disparity, k)

    def _near_wide_unmatched(self, disparity: np.ndarray, x: np.ndarray, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        """True where an unmatched region at least ``unmatched_min_radius`` wide lies within the
        keypoint's neighbourhood (radius ``r``)."""
        k = self.params.unmatched_min_radius
        hole = (disparity <= _BM_INVALID).astype(np.uint8)
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))
        wide = cv2.morphologyEx(hole, cv2.MORPH_OPEN, disc)
        out = np.zeros(len(x), bool)
        for rad in np.unique(r).tolist():
            sel = r == rad
            near = cv2.dilate(wide, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rad + 1, 2 * rad + 1)))
            out[sel] = near[y[sel], x[sel]] > 0
        return out

    def radii(self, octave: np.ndarray | None, scale_factor: float) -> np.ndarray:
        """Neighbourhood radius per keypoint in downscaled px: ``window_px`` at level 0, times
        scale_factor^octave when ``octave_scaled`` (the SAD window and the ORB patch of a level-L
        keypoint cover scale^L times as many level-0 pixels)."""
        p = self.params
        if octave is None or not p.octave_scaled:
            return np.full(0 if octave is None else len(octave), self.radius, np.int64)
        return np.ceil(p.window_px * scale_factor ** np.asarray(octave, float) / p.downscale).astype(np.int64)

    def flags(self, disparity: np.ndarray, first_col: int, uv: np.ndarray, octave: np.ndarray | None = None,
              scale_factor: float = 1.2) -> np.ndarray:
        """(N,) True where the keypoints (level-0 px; pyramid ``octave``) sit on a contour of
        ``disparity``."""
        n = len(uv)
        out = np.zeros(n, bool)
        if n == 0:
            return out
        s = self.params.downscale
        h, w = disparity.shape
        x = np.clip(np.round(uv[:, 0] / s).astype(np.int64), 0, w - 1)
        y = np.clip(np.round(uv[:, 1] / s).astype(np.int64), 0, h - 1)
        r = self.radii(octave, scale_factor) if octave is not None else np.full(n, self.radius, np.int64)
        hi, lo = np.empty(n, np.float32), np.empty(n, np.float32)
        for rad in np.unique(r).tolist():
            sel = r == rad
            dmax, dmin = self._min_max(disparity, rad)
            hi[sel], lo[sel] = dmax[y[sel], x[sel]], dmin[y[sel], x[sel]]
        # unmatched anywhere near (lo == 0: background or occluded) or a disparity step > ratio
        unmatched = lo <= _BM_INVALID
        step = (hi > (1.0 + self.params.ratio) * lo) & ~unmatched
        if self.params.unmatched_is_contour:
            step |= unmatched if self.params.unmatched_min_radius <= 0 else \
                self._near_wide_unmatched(disparity, x, y, r)
        # left of first_col block matching cannot match at all: no evidence either way
        judged = x - r >= first_col
        out[:] = step & judged
        return out

    def __call__(self, left: np.ndarray, right: np.ndarray, uv: np.ndarray, octave: np.ndarray | None = None,
                 scale_factor: float = 1.2) -> np.ndarray:
        d, first = self.disparity(left, right)
        if not self.reliable(d, first):
            return np.zeros(len(uv), bool)
        on = self.flags(d, first, uv, octave, scale_factor)
        if len(on) and on.mean() > self.params.max_flagged_fraction:
            return np.zeros(len(uv), bool)
        return on

    @staticmethod
    def matched_fraction(disparity: np.ndarray, first_col: int) -> float:
        """Fraction of the searchable image (right of ``first_col``) block matching matched."""
        searchable = disparity[:, first_col:]
        return float((searchable > _BM_INVALID).mean()) if searchable.size else 0.0

    def reliable(self, disparity: np.ndarray, first_col: int) -> bool:
        """Whether this frame's dense disparity is evidence at all (``min_matched_fraction``)."""
        p = self.params
        return p.min_matched_fraction <= 0.0 or self.matched_fraction(disparity, first_col) >= p.min_matched_fraction
