"""Common machinery of the stereo dataset sources.

A source is opened once (calibration, stamps, ground truth and the list of
image files are read eagerly, they are small) and yields rectified grey
frames lazily, one pair read from disk per ``frame(i)`` call, so a long
sequence never sits in memory.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator, Sequence

import cv2
import numpy as np
import yaml

from shared.errors import InputError, warn_input
from shared.types import StereoCalibration, StereoFrame, Trajectory

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp", ".tif", ".tiff")
# Smallest usable image side: ORB needs a 31 px border on the finest pyramid level plus room to
# find corners; anything smaller cannot be tracked and would fail deep inside OpenCV.
MIN_IMAGE_SIDE_PX = 64

# A rectifier turns a raw (left, right) pair into the rectified pair; the
# identity for datasets that ship rectified images (KITTI, plain folders).
Rectifier = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


class StereoSource:
    """A finite, indexable sequence of rectified stereo frames.

    Attributes
    ----------
    name: short human-readable name (dataset kind and folder).
    calibration: pinhole model of the *rectified* pair.
    rate_hz: nominal frame rate.
    timestamps: (N,) float64 seconds, strictly increasing.
    ground_truth: ``T_world_cam`` of the rectified left camera for the frames
        that have one (stamps equal to those frames' stamps), or None.
        ``ground_truth.meta["frame_indices"]`` lists which frames they are.
    left_paths, right_paths: the raw image files, one per frame.
    """

    def __init__(
        self,
        *,
        name: str,
        root: Path,
        calibration: StereoCalibration,
        rate_hz: float,
        timestamps: np.ndarray,
        left_paths: Sequence[Path],
        right_paths: Sequence[Path],
        ground_truth: Trajectory | None = None,
        rectifier: Rectifier | None = None,
    ):
        self.name = name
        self.root = Path(root)
        self.calibration = calibration
        self.rate_hz = float(rate_hz)
        self.timestamps = np.asarray(timestamps, dtype=np.float64).reshape(-1)
        self.left_paths = [Path(p) for p in left_paths]
        self.right_paths = [Path(p) for p in right_paths]
        self.ground_truth = ground_truth
        self._rectifier = rectifier
        if not (len(self.timestamps) == len(self.left_paths) == len(self.right_paths)):
            raise AssertionError("source built with inconsistent frame lists")  # programming error
        if len(self.timestamps) == 0:
            raise InputError(self.root, "no stereo frames found")
        if len(self.timestamps) > 1 and not np.all(np.diff(self.timestamps) > 0):
            raise InputError(self.root, "frame timestamps are not strictly increasing")
        w, h = self.image_size
        if min(w, h) < MIN_IMAGE_SIDE_PX:
            raise InputError(self.left_paths[0], f"images are {w}x{h}; at least {MIN_IMAGE_SIDE_PX}x"
                                                 f"{MIN_IMAGE_SIDE_PX} pixels are needed to track features")
        self._probe_first_pair()

    def _probe_first_pair(self) -> None:
        """Read the first pair as stored, before any process starts: a corrupt first image fails
        here, and images that will be converted (colour, 16-bit) are announced once."""
        for path in (self.left_paths[0], self.right_paths[0]):
            raw = read_image_as_stored(path)
            notes = []
            if raw.ndim == 3 and raw.shape[2] > 1:
                notes.append(f"{raw.shape[2]}-channel colour converted to grey")
            if raw.dtype != np.uint8:
                notes.append(f"{raw.dtype} pixels scaled to 8 bit (value / 256 for 16-bit)")
            if notes:
                warn_input(path.parent, f"images are used converted: {'; '.join(notes)} "
                                        f"(first: {path.name})")
        self.raw_pair(0)  # sizes of the pair against each other and the calibration

    # -- sequence protocol -------------------------------------------------
    def __len__(self) -> int:
        return len(self.timestamps)

    def __iter__(self) -> Iterator[StereoFrame]:
        for i in range(len(self)):
            yield self.frame(i)

    def __repr__(self) -> str:
        w, h = self.image_size
        return f"{type(self).__name__}({self.name!r}, {len(self)} frames, {w}x{h}, {self.rate_hz:g} Hz)"

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the rectified images."""
        return self.calibration.width, self.calibration.height

    def raw_pair(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The pair as stored on disk (grey, not rectified), size-checked."""
        i = self._check_index(i)
        left = read_grey(self.left_paths[i])
        right = read_grey(self.right_paths[i])
        if left.shape != right.shape:
            raise InputError(
                self.right_paths[i],
                f"right image is {right.shape[1]}x{right.shape[0]} but left image "
                f"{self.left_paths[i].name} is {left.shape[1]}x{left.shape[0]}",
            )
        w, h = self.image_size
        if left.shape != (h, w):
            raise InputError(
                self.left_paths[i],
                f"image is {left.shape[1]}x{left.shape[0]} but the calibration says {w}x{h}",
            )
        return left, right

    def frame(self, i: int) -> StereoFrame:
        """Frame ``i``: rectified uint8 grey left/right images read from disk now."""
        i = self._check_index(i)
        left, right = self.raw_pair(i)
        if self._rectifier is not None:
            left, right = self._rectifier(left, right)
        return StereoFrame(index=i, timestamp=float(self.timestamps[i]), left=left, right=right)

    def _check_index(self, i: int) -> int:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for {n} frames")
        return i % n


# -- helpers shared by the loaders ---------------------------------------------

def read_grey(path: Path) -> np.ndarray:
    """Read an image as uint8 grey; a missing or corrupt file is an InputError."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found")
    # IMREAD_GRAYSCALE also converts colour JPGs and reduces 16-bit PNGs to 8 bit.
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None or img.size == 0:
        raise InputError(path, "cannot decode image (corrupt or unsupported format)")
    return img


def read_image_as_stored(path: Path) -> np.ndarray:
    """Read an image without any conversion (channels and bit depth as stored)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise InputError(path, "cannot decode image (corrupt or unsupported format)")
    return img


def require_dir(path: Path, what: str) -> Path:
    if not path.is_dir():
        raise InputError(path, f"{what} folder not found")
    return path


def require_file(path: Path, what: str) -> Path:
    if not path.is_file():
        raise InputError(path, f"{what} not found")
    return path


def read_text(path: Path, what: str = "file") -> str:
    """File contents as text; unreadable or binary files are an InputError."""
    try:
        return Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read {what} ({exc})") from None


def load_yaml_file(path: Path) -> dict:
    """Read a (possibly OpenCV-flavoured) YAML mapping, naming the file on error."""
    text = read_text(path, "YAML file")
    # EuRoC files start with OpenCV's "%YAML:1.0", which PyYAML rejects as a
    # malformed directive; drop directive lines, the rest is plain YAML.
    text = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("%"))
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputError(path, f"not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise InputError(path, "expected a mapping of keys to values")
    return data


def numbers(value, count: int | None, path: Path, field: str) -> np.ndarray:
    """``value`` as a float64 vector of ``count`` finite numbers, else InputError naming ``field``."""
    if value is None:
        raise InputError(path, f"missing required field '{field}'")
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(path, f"field '{field}' is not numeric: {value!r}") from None
    if count is not None and arr.size != count:
        raise InputError(path, f"field '{field}' needs {count} numbers, got {arr.size}")
    check_finite(arr, path, field)
    return arr


def check_finite(arr: np.ndarray, path: Path, field: str) -> None:
    """InputError naming the first non-finite number of ``arr`` (1-based, as a user counts)."""
    bad = np.nonzero(~np.isfinite(arr))[0]
    if len(bad):
        raise InputError(path, f"field '{field}': number {bad[0] + 1} of {arr.size} is not finite "
                               f"({arr[bad[0]]}){f'; {len(bad)} are not' if len(bad) > 1 else ''}")


def number(mapping: dict, key: str, path: Path, default: float | None = None, positive: bool = False) -> float:
    """Scalar field ``key`` of ``mapping``; missing (without default) or non-numeric is an InputError."""
    if key not in mapping or mapping[key] is None:
        if default is None:
            raise InputError(path, f"missing required field '{key}'")
        return float(default)
    value = mapping[key]
    if isinstance(value, bool):
        raise InputError(path, f"field '{key}' is not numeric: {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(path, f"field '{key}' is not numeric: {value!r}") from None
    if not np.isfinite(x):
        raise InputError(path, f"field '{key}' is not finite: {value!r}")
    if positive and x <= 0:
        raise InputError(path, f"field '{key}' must be positive, got {x:g}")
    return x


def read_number_table(path: Path, columns: int | Sequence[int], what: str) -> np.ndarray:
    """Whitespace/comma separated numeric table with ``#`` comments, as (N, C) float64.

    ``columns`` is the exact column count, or a set of accepted counts.
    """
    text = read_text(path, what)
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].replace(",", " ").strip()
        if not line:
            continue
        try:
            rows.append([float(tok) for tok in line.split()])
        except ValueError:
            raise InputError(path, f"line {lineno}: non-numeric value in {what}: {line[:60]!r}") from None
        accepted = (columns,) if isinstance(columns, int) else tuple(columns)
        if len(rows[-1]) not in accepted:
            raise InputError(
                path, f"line {lineno}: {what} rows need {' or '.join(map(str, accepted))} numbers, got {len(rows[-1])}"
            )
    if not rows:
        return np.zeros((0, columns if isinstance(columns, int) else max(columns)))
    width = {len(r) for r in rows}
    if len(width) != 1:
        raise InputError(path, f"{what} rows have differing numbers of columns")
    table = np.asarray(rows, dtype=np.float64)
    if not np.all(np.isfinite(table)):
        raise InputError(path, f"{what} contains non-finite values")
    return table


def nearest_match(query: np.ndarray, ref: np.ndarray, tol) -> tuple[np.ndarray, np.ndarray]:
    """Match each query stamp to the nearest ``ref`` stamp within ``tol``.

    Works on int64 nanoseconds or float seconds alike. ``ref`` must be sorted.
    Returns (query indices that matched, their ref indices); vectorised with
    searchsorted, so it stays O(N log M).
    """
    query = np.asarray(query)
    ref = np.asarray(ref)
    if len(ref) == 0 or len(query) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    hi = np.clip(np.searchsorted(ref, query), 1, len(ref) - 1) if len(ref) > 1 else np.zeros(len(query), int)
    lo = np.maximum(hi - 1, 0)
    d_lo = np.abs(query - ref[lo])
    d_hi = np.abs(ref[hi] - query)
    best = np.where(d_hi < d_lo, hi, lo)
    dist = np.minimum(d_lo, d_hi)
    ok = dist <= tol
    return np.nonzero(ok)[0].astype(np.int64), best[ok].astype(np.int64)


def truncate(max_frames: int | None, n: int, where: Path) -> int:
    """Number of frames to keep given ``max_frames``."""
    if max_frames is None:
        return n
    if isinstance(max_frames, bool) or not isinstance(max_frames, (int, np.integer)) or max_frames < 1:
        raise InputError(where, f"max_frames must be a positive integer, got {max_frames!r}")
    return min(n, int(max_frames))


def rate_from_stamps(stamps: np.ndarray, fallback: float) -> float:
    """Frame rate from the median frame interval (robust to dropped frames)."""
    if len(stamps) < 2:
        return float(fallback)
    dt = float(np.median(np.diff(stamps)))
    return 1.0 / dt if dt > 0 else float(fallback)


def warn_unmatched(left_dir: Path, right_dir: Path, left_only: Sequence[str], right_only: Sequence[str]) -> None:
    """Images without a twin on the other side are skipped, with one warning per side."""
    for folder, names, other in ((left_dir, left_only, right_dir), (right_dir, right_only, left_dir)):
        if len(names):
            warn_input(folder, f"{len(names)} image(s) have no twin in {other.name}/ and are skipped "
                               f"(first: {names[0]})")
