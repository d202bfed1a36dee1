"""KITTI odometry stereo source (images already rectified).

Layout: ``calib.txt``, ``times.txt``, optional ``poses.txt`` (ground truth,
usually kept apart in ``dataset/poses/NN.txt``: copy it in) and grey images in
``image_0/`` + ``image_1/`` (official) or ``image_l/`` + ``image_r/``.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from shared.errors import InputError
from shared.types import StereoCalibration, Trajectory

from .base import (
    IMAGE_SUFFIXES,
    StereoSource,
    rate_from_stamps,
    read_grey,
    read_number_table,
    read_text,
    require_dir,
    require_file,
    truncate,
    warn_unmatched,
)

IMAGE_DIR_PAIRS = (("image_0", "image_1"), ("image_l", "image_r"))
_KEY = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)$")


def parse_kitti_calib(path: Path) -> dict[str, np.ndarray]:
    """calib.txt -> {"P0": 3x4, "P1": 3x4, ...}.

    Accepts the official file ("P0: 12 numbers" ... "Tr: ...", 5 lines) and
    the bare form (P0 and P1 as two lines of 12 numbers, no prefixes).
    """
    require_file(path, "KITTI calibration calib.txt")
    mats: dict[str, np.ndarray] = {}
    bare = 0
    for lineno, line in enumerate(read_text(path, "calibration").splitlines(), 1):
        if not line.strip():
            continue
        m = _KEY.match(line)
        if m:
            key, body = m.group(1), m.group(2)
        else:
            # Bare lines are P0, P1, P2, ... in order.
            key, body = f"P{bare}", line
            bare += 1
        try:
            vals = np.array([float(t) for t in body.split()], dtype=np.float64)
            problem = None if vals.size == 12 else f"needs 12 numbers, got {vals.size}"
            bad = np.nonzero(~np.isfinite(vals))[0]
            if problem is None and len(bad):
                problem = f"number {bad[0] + 1} of 12 is not finite ({vals[bad[0]]})"
        except ValueError:
            problem = "is not numeric"
        if problem is None:
            mats[key] = vals.reshape(3, 4)
        elif key in ("P0", "P1"):
            raise InputError(path, f"line {lineno}: field '{key}' {problem}")
        # Other entries (P2, P3, Tr, or extra keys of other KITTI calib files)
        # are not needed; a malformed one is ignored rather than fatal.
    for key in ("P0", "P1"):
        if key not in mats:
            raise InputError(path, f"missing required field '{key}' (3x4 projection matrix)")
    return mats


def calibration_from_projections(P0: np.ndarray, P1: np.ndarray, width: int, height: int, path: Path) -> StereoCalibration:
    fx, fy, cx, cy = P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2]
    if fx <= 0 or fy <= 0 or P1[0, 0] <= 0:
        raise InputError(path, "field 'P0'/'P1': focal length must be positive")
    # P1[0,3] = -fx * baseline relative to cam0 (P0[0,3] is 0 for KITTI's
    # grey reference camera; subtracting it keeps this right if it is not).
    baseline = float(-(P1[0, 3] - P0[0, 3]) / P1[0, 0])
    if baseline <= 0:
        raise InputError(path, f"field 'P1' gives a non-positive baseline ({baseline:g} m)")
    return StereoCalibration(
        fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy),
        baseline=baseline, width=int(width), height=int(height),
    )


def _indexed_images(folder: Path) -> dict[int, Path]:
    """{frame index: path} for files named like 000123.png."""
    out = {}
    for p in folder.iterdir():
        if p.suffix.lower() in IMAGE_SUFFIXES and p.stem.isdigit():
            out[int(p.stem)] = p
    return out


class KittiSource(StereoSource):
    def __init__(self, path: str | Path, max_frames: int | None = None):
        path = Path(path)
        require_dir(path, "KITTI sequence")
        for left_name, right_name in IMAGE_DIR_PAIRS:
            if (path / left_name).is_dir():
                left_dir = path / left_name
                right_dir = require_dir(path / right_name, f"KITTI right image ({right_name})")
                break
        else:
            raise InputError(path, "no image_0/ + image_1/ (or image_l/ + image_r/) folders")

        mats = parse_kitti_calib(path / "calib.txt")
        times_path = require_file(path / "times.txt", "KITTI timestamps times.txt")
        times = read_number_table(times_path, 1, "timestamps")[:, 0]

        # Frames are identified by the image file index (000042.png -> row 42 of
        # times.txt / poses.txt), so a folder holding a subset still lines up.
        left, right = _indexed_images(left_dir), _indexed_images(right_dir)
        indices = sorted(set(left) & set(right))
        if not indices:
            raise InputError(left_dir, "no stereo pairs (numbered images present in both folders)")
        warn_unmatched(left_dir, right_dir, [left[i].name for i in sorted(set(left) - set(right))],
                       [right[i].name for i in sorted(set(right) - set(left))])
        indices = indices[: truncate(max_frames, len(indices), path)]
        idx = np.asarray(indices, dtype=np.int64)
        if idx[-1] >= len(times):
            raise InputError(times_path, f"has {len(times)} stamps but image {left[int(idx[-1])].name} needs row {idx[-1]}")
        stamps = times[idx]

        first = read_grey(left[indices[0]])
        calibration = calibration_from_projections(mats["P0"], mats["P1"], first.shape[1], first.shape[0], path / "calib.txt")

        ground_truth = None
        poses_path = path / "poses.txt"
        if poses_path.is_file():
            rows = read_number_table(poses_path, 12, "KITTI poses")
            have = np.nonzero(idx < len(rows))[0]
            if len(have):
                # Each row is T_world_cam0 (3x4, row-major) of the rectified left
                # camera; the world frame is the first camera pose.
                T = np.tile(np.eye(4), (len(have), 1, 1))
                T[:, :3, :] = rows[idx[have]].reshape(-1, 3, 4)
                ground_truth = Trajectory(
                    stamps[have], T,
                    meta={"frame": "rectified left camera", "source": str(poses_path),
                          "frame_indices": have.tolist()},
                )

        super().__init__(
            name=f"kitti:{path.resolve().name}",
            root=path,
            calibration=calibration,
            rate_hz=rate_from_stamps(stamps, 10.0),
            timestamps=stamps,
            left_paths=[left[i] for i in indices],
            right_paths=[right[i] for i in indices],
            ground_truth=ground_truth,
        )
