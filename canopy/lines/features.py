"""Line segment detection (FLD or LSD, AGRI §3.2.1) and LBD binary description.

``detect_segments`` returns (N,4) float32 rows (x1, y1, x2, y2) in pixels, sorted by length
(longest first). Both detectors orient a segment by the gradient polarity of its edge, so
the same edge seen in the left and right images of a rectified pair keeps its direction;
the LBD descriptor is computed in that oriented frame.

Every segment passes ``sanitize_segments`` at the boundary: NaN / infinite endpoints, zero
length, endpoints outside the image and segments shorter than the minimum length are
rejected and counted, never passed on.

Descriptors: OpenCV contrib's ``BinaryDescriptor.compute`` (the LBD of Zhang & Koch 2013:
9 bands of ``lbd_band_width`` rows along the line, gradient statistics per band,
binarised pairwise band comparisons, 256 bits) on ``KeyLine`` objects built from our
segments (octave 0, class_id = row index, angle = direction of the oriented segment,
numOfPixels = length: the support region LBD integrates along).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy.lines.params import LineParams
from shared.errors import InputError

DESCRIPTOR_BYTES = 32
REJECT_KEYS = ("nan", "zero_length", "outside", "short")
# FLD asserts inside OpenCV on images narrower than 6 px; below this side no segment is sought
MIN_IMAGE_SIDE = 8


def _grey(image: np.ndarray, what: str) -> np.ndarray:
    if image is None or not isinstance(image, np.ndarray) or image.size == 0:
        raise InputError(what, "empty or missing image")
    if image.ndim == 3 and image.shape[2] in (3, 4):
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if image.ndim != 2:
        raise InputError(what, f"expected a grey image, got shape {image.shape}")
    if image.dtype != np.uint8:
        raise InputError(what, f"expected uint8 pixels, got {image.dtype}")
    return np.ascontiguousarray(image)


def min_length_px(width: int, height: int, params: LineParams) -> float:
    return params.min_length_fraction * float(np.hypot(width, height))


def segment_lengths(segs: np.ndarray) -> np.ndarray:
    s = np.asarray(segs, np.float64).reshape(-1, 4)
    return np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1])


def sanitize_segments(segs, width: int, height: int, min_length: float, border: float = 0.5):
    """Reject degenerate segments; returns ((K,4) float32 kept, kept indices, counts per reason).

    Reasons are counted in order (a segment is counted once, under its first failure):
    ``nan`` (non-finite endpoint), ``zero_length``, ``outside`` (an endpoint beyond the
    image by more than ``border`` px), ``short`` (shorter than ``min_length``).
    """
    s = np.asarray(segs, np.float64)
    if s.size == 0:
        return np.zeros((0, 4), np.float32), np.zeros(0, np.int64), dict.fromkeys(REJECT_KEYS, 0)
    s = s.reshape(-1, 4)
    finite = np.isfinite(s).all(axis=1)
    s0 = np.where(finite[:, None], s, 0.0)
    length = np.hypot(s0[:, 2] - s0[:, 0], s0[:, 3] - s0[:, 1])
    nonzero = length > 1e-6
    x, y = s0[:, [0, 2]], s0[:, [1, 3]]
    inside = ((x >= -border) & (x <= width - 1 + border) & (y >= -border) & (y <= height - 1 + border)).all(axis=1)
    long_enough = length >= min_length
    counts = {}
    alive = np.ones(len(s), bool)
    for key, ok in zip(REJECT_KEYS, (finite, nonzero, inside, long_enough)):
        counts[key] = int((alive & ~ok).sum())
        alive &= ok
    idx = np.flatnonzero(alive)
    return s[idx].astype(np.float32), idx, counts


def _raw_fld(grey: np.ndarray, min_len: float, params: LineParams) -> np.ndarray:
    fld = cv2.ximgproc.createFastLineDetector(
        max(int(np.floor(min_len)), 1), float(params.fld_distance_threshold), float(params.fld_canny_low),
        float(params.fld_canny_high), int(params.fld_canny_aperture), bool(params.fld_merge))
    return fld.detect(grey)


def _raw_lsd(grey: np.ndarray, min_len: float, params: LineParams) -> np.ndarray:
    lsd = cv2.createLineSegmentDetector(
        cv2.LSD_REFINE_STD, float(params.lsd_scale), float(params.lsd_sigma_scale), 2.0,
        float(params.lsd_angle_tolerance_deg), 0.0, float(params.lsd_density), 1024)
    return lsd.detect(grey)[0]


_DETECTORS = {"fld": _raw_fld, "lsd": _raw_lsd}


def detect_segments(image: np.ndarray, params: LineParams) -> tuple[np.ndarray, dict]:
    """Detect line segments; returns ((N,4) float32 longest first, stats dict).

    stats: ``detected`` (raw detector output), one count per rejection reason
    (``nan``, ``zero_length``, ``outside``, ``short``), ``capped`` (dropped by
    ``max_lines``), ``kept``, and ``image_too_small`` (1 when the image is smaller than
    ``MIN_IMAGE_SIDE`` and no detection was attempted).
    """
    grey = _grey(image, "detect_segments")
    h, w = grey.shape
    min_len = min_length_px(w, h, params)
    too_small = min(h, w) < MIN_IMAGE_SIDE
    raw = None if too_small else _DETECTORS[params.detector](grey, min_len, params)
    # OpenCV returns None (nothing found), (N,1,4) or (N,4)
    raw = np.zeros((0, 4), np.float32) if raw is None else np.asarray(raw, np.float32).reshape(-1, 4)
    segs, _, counts = sanitize_segments(raw, w, h, min_len, params.border_tolerance)
    order = np.argsort(-segment_lengths(segs), kind="stable")
    capped = max(len(order) - params.max_lines, 0)
    segs = segs[order[: params.max_lines]]
    stats = {"detected": int(len(raw)), **counts, "capped": int(capped), "kept": int(len(segs)),
             "image_too_small": int(too_small)}
    return np.ascontiguousarray(segs), stats


def _keylines(segs: np.ndarray) -> list:
    KeyLine = cv2.line_descriptor.KeyLine
    out = []
    for i, (x1, y1, x2, y2) in enumerate(np.asarray(segs, np.float64)):
        dx, dy = x2 - x1, y2 - y1
        length = float(np.hypot(dx, dy))
        kl = KeyLine()
        kl.startPointX, kl.startPointY, kl.endPointX, kl.endPointY = float(x1), float(y1), float(x2), float(y2)
        kl.sPointInOctaveX, kl.sPointInOctaveY = float(x1), float(y1)
        kl.ePointInOctaveX, kl.ePointInOctaveY = float(x2), float(y2)
        kl.pt = (float(0.5 * (x1 + x2)), float(0.5 * (y1 + y2)))
        kl.angle = float(np.arctan2(dy, dx))
        kl.lineLength = length
        kl.size = length
        kl.numOfPixels = max(int(round(length)), 1)
        kl.response = length
        kl.octave = 0
        kl.class_id = i
        out.append(kl)
    return out


class LineDescriber:
    """LBD descriptors of given segments (one OpenCV ``BinaryDescriptor``, reused)."""

    def __init__(self, params: LineParams):
        bd = cv2.line_descriptor.BinaryDescriptor_createBinaryDescriptor()
        bd.setWidthOfBand(int(params.lbd_band_width))
        bd.setReductionRatio(int(params.lbd_reduction_ratio))
        bd.setNumOfOctaves(1)
        self._bd = bd

    def __call__(self, image: np.ndarray, segs: np.ndarray) -> np.ndarray:
        """(N,32) uint8 LBD descriptors, row i for segment i."""
        segs = np.asarray(segs, np.float32).reshape(-1, 4)
        if len(segs) == 0:  # OpenCV prints an error and returns nothing for an empty list
            return np.zeros((0, DESCRIPTOR_BYTES), np.uint8)
        grey = _grey(image, "describe_segments")
        _, desc = self._bd.compute(grey, _keylines(segs))
        desc = np.asarray(desc, np.uint8).reshape(-1, DESCRIPTOR_BYTES)
        if len(desc) != len(segs):
            raise RuntimeError(f"LBD returned {len(desc)} descriptors for {len(segs)} segments")
        return np.ascontiguousarray(desc)


def describe_segments(image: np.ndarray, segs: np.ndarray, params: LineParams) -> np.ndarray:
    return LineDescriber(params)(image, segs)
