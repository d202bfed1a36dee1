"""Plain stereo folder: rectified ``left/`` + ``right/`` images and ``calib.yaml``.

``calib.yaml`` keys: fx, fy, cx, cy, baseline (metres) required; rate_hz
(default 20), width/height (checked against the images if given) optional.
Optional ``times.txt`` (one stamp in seconds per image, in name order) and
``groundtruth.txt`` (TUM: ``t x y z qx qy qz qw``, T_world_cam of the left
camera) are used when present.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from shared.errors import InputError
from shared.geometry import poses_from_xyz_quat_wxyz
from shared.types import StereoCalibration, Trajectory

from .base import (
    IMAGE_SUFFIXES,
    StereoSource,
    load_yaml_file,
    nearest_match,
    number,
    read_grey,
    read_number_table,
    require_dir,
    require_file,
    truncate,
    warn_unmatched,
)

DEFAULT_RATE_HZ = 20.0


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


class FolderSource(StereoSource):
    def __init__(self, path: str | Path, max_frames: int | None = None):
        path = Path(path)
        require_dir(path, "stereo image")
        left_dir = require_dir(path / "left", "left image")
        right_dir = require_dir(path / "right", "right image")
        calib_path = require_file(path / "calib.yaml", "calibration calib.yaml")
        calib = load_yaml_file(calib_path)
        fx, fy, cx, cy = (number(calib, k, calib_path) for k in ("fx", "fy", "cx", "cy"))
        baseline = number(calib, "baseline", calib_path, positive=True)
        rate = number(calib, "rate_hz", calib_path, default=DEFAULT_RATE_HZ, positive=True)
        if fx <= 0 or fy <= 0:
            raise InputError(calib_path, "fields 'fx' and 'fy' must be positive")

        left = _images(left_dir)
        if not left:
            raise InputError(left_dir, "no images (png/jpg/...) found")
        right_by_name = {p.name: p for p in _images(right_dir)}
        left_names = {p.name for p in left}
        warn_unmatched(left_dir, right_dir, [p.name for p in left if p.name not in right_by_name],
                       sorted(set(right_by_name) - left_names))
        # times.txt, when given, has one stamp per left image: keep the stamps of paired images only.
        paired = np.array([p.name in right_by_name for p in left], dtype=bool)
        left_all = left
        left = [p for p in left if p.name in right_by_name]
        if not left:
            raise InputError(left_dir, f"no stereo pairs: no image has a twin of the same name in {right_dir.name}/")
        n_all = len(left)
        n = truncate(max_frames, n_all, path)

        times_path = path / "times.txt"
        if times_path.is_file():
            times = read_number_table(times_path, 1, "timestamps")[:, 0]
            if len(times) != len(left_all):
                raise InputError(times_path, f"has {len(times)} stamps for {len(left_all)} left images")
            stamps = times[paired][:n]
        else:
            stamps = np.arange(n, dtype=np.float64) / rate

        first = read_grey(left[0])
        h, w = first.shape
        for key, actual in (("width", w), ("height", h)):
            if key in calib and number(calib, key, calib_path) != actual:
                raise InputError(left[0], f"image {key} is {actual} but {calib_path.name} says {calib[key]}")
        calibration = StereoCalibration(fx=fx, fy=fy, cx=cx, cy=cy, baseline=baseline, width=w, height=h)

        ground_truth = None
        gt_path = path / "groundtruth.txt"
        if gt_path.is_file():
            tum = read_number_table(gt_path, 8, "TUM ground truth")
            tum = tum[np.argsort(tum[:, 0], kind="stable")]
            if np.any(np.linalg.norm(tum[:, 4:8], axis=1) < 1e-9):
                raise InputError(gt_path, "ground truth contains a zero quaternion")
            # Half a frame period: a GT sample that close belongs unambiguously to this frame.
            fi, gi = nearest_match(stamps, tum[:, 0], 0.5 / rate)
            if len(fi):
                q_wxyz = tum[gi][:, [7, 4, 5, 6]]  # TUM stores qx qy qz qw
                ground_truth = Trajectory(
                    stamps[fi], poses_from_xyz_quat_wxyz(tum[gi, 1:4], q_wxyz),
                    meta={"frame": "left camera (as given)", "source": str(gt_path),
                          "frame_indices": fi.tolist()},
                )

        super().__init__(
            name=f"folder:{path.resolve().name}",
            root=path,
            calibration=calibration,
            rate_hz=rate,
            timestamps=stamps,
            left_paths=left[:n],
            right_paths=[right_by_name[p.name] for p in left[:n]],
            ground_truth=ground_truth,
        )
