"""EuRoC MAV (ASL folder layout) stereo source with on-the-fly rectification.

Layout: ``<path>/mav0/{cam0,cam1}/{sensor.yaml,data.csv,data/<stamp>.png}``
and optionally ``mav0/state_groundtruth_estimate0/data.csv``.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from shared.errors import InputError, warn_input
from shared.geometry import poses_from_xyz_quat_wxyz
from shared.types import StereoCalibration, Trajectory

from .base import (
    StereoSource,
    load_yaml_file,
    nearest_match,
    number,
    numbers,
    read_text,
    require_dir,
    require_file,
    truncate,
)

# Ground truth rows are matched to camera stamps by nearest stamp: the
# vicon2gt-based GT bundled with the project has some stamps 256 ns off the
# camera stamps (float64 round-off in the tool that wrote it).
GT_TOLERANCE_NS = 1_000_000


class _CameraModel:
    """One camera's sensor.yaml: pinhole + radial-tangential, extrinsics to body."""

    def __init__(self, path: Path):
        data = load_yaml_file(path)
        model = str(data.get("camera_model", "pinhole")).lower()
        if model != "pinhole":
            raise InputError(path, f"camera_model '{model}' is not supported (pinhole only)")
        dist_model = str(data.get("distortion_model", "radial-tangential")).lower()
        if dist_model not in ("radial-tangential", "radtan", "plumb_bob"):
            raise InputError(path, f"distortion_model '{dist_model}' is not supported (radial-tangential only)")
        fu, fv, cu, cv = numbers(data.get("intrinsics"), 4, path, "intrinsics")
        self.K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
        self.D = numbers(data.get("distortion_coefficients"), None, path, "distortion_coefficients")
        if self.D.size not in (4, 5, 8):
            raise InputError(path, f"field 'distortion_coefficients' needs 4 or 5 numbers, got {self.D.size}")
        res = numbers(data.get("resolution"), 2, path, "resolution")
        if np.any(res <= 0) or np.any(res != np.round(res)):
            raise InputError(path, f"field 'resolution' must be two positive integers, got {res.tolist()}")
        self.width, self.height = int(res[0]), int(res[1])
        t_bs = data.get("T_BS")
        self.T_B_S = numbers(t_bs.get("data") if isinstance(t_bs, dict) else t_bs, 16, path, "T_BS").reshape(4, 4)
        if not np.allclose(self.T_B_S[3], [0, 0, 0, 1]) or abs(np.linalg.det(self.T_B_S[:3, :3]) - 1) > 1e-3:
            raise InputError(path, "field 'T_BS' is not a rigid transform")
        # Optional: without it the rate comes from the frame stamps.
        self.rate_hz = number(data, "rate_hz", path, default=-1.0)


def _read_image_list(csv_path: Path) -> dict[int, str]:
    """``data.csv`` of a camera: {stamp_ns: file name}."""
    require_file(csv_path, "camera image list data.csv")
    out: dict[int, str] = {}
    for lineno, line in enumerate(read_text(csv_path, "CSV file").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        try:
            stamp = int(parts[0])
        except ValueError:
            raise InputError(csv_path, f"line {lineno}: timestamp {parts[0]!r} is not an integer (ns)") from None
        out[stamp] = parts[1] if len(parts) > 1 and parts[1] else f"{stamp}.png"
    return out


def _read_groundtruth(csv_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """EuRoC state estimate CSV -> (stamps_ns int64 (M,), T_world_body (M, 4, 4)), sorted."""
    stamps, rows = [], []
    for lineno, line in enumerate(read_text(csv_path, "CSV file").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split(",")
        try:
            # Stamps stay integers: as float64 they would lose ~256 ns.
            stamps.append(int(parts[0]))
            rows.append([float(v) for v in parts[1:8]])
        except ValueError:
            raise InputError(csv_path, f"line {lineno}: non-numeric ground-truth value") from None
        if len(rows[-1]) != 7:
            raise InputError(csv_path, f"line {lineno}: needs timestamp, p(3), q_wxyz(4)")
    if not rows:
        raise InputError(csv_path, "ground-truth file has no rows")
    st = np.asarray(stamps, dtype=np.int64)
    pq = np.asarray(rows, dtype=np.float64)
    if not np.all(np.isfinite(pq)) or np.any(np.linalg.norm(pq[:, 3:7], axis=1) < 1e-6):
        raise InputError(csv_path, "ground truth contains non-finite values or zero quaternions")
    order = np.argsort(st, kind="stable")
    return st[order], poses_from_xyz_quat_wxyz(pq[order, :3], pq[order, 3:7])


def _ns_to_seconds(ns: np.ndarray) -> np.ndarray:
    # Split to keep the sub-second part exact before the float64 conversion.
    ns = np.asarray(ns, dtype=np.int64)
    return (ns // 1_000_000_000).astype(np.float64) + (ns % 1_000_000_000).astype(np.float64) * 1e-9


class EurocSource(StereoSource):
    """EuRoC ASL stereo pair, rectified with OpenCV from the sensor.yaml calibration."""

    def __init__(self, path: str | Path, max_frames: int | None = None):
        path = Path(path)
        require_dir(path, "EuRoC dataset")
        if (path / "mav0").is_dir():
            mav0 = path / "mav0"
        elif (path / "cam0").is_dir() or path.name == "mav0":
            mav0 = path
        else:
            raise InputError(path, "not an EuRoC ASL folder (no mav0/ or cam0/ inside)")
        cam_dirs = [require_dir(mav0 / c, f"EuRoC camera {c}") for c in ("cam0", "cam1")]
        cams = [_CameraModel(require_file(d / "sensor.yaml", "camera calibration sensor.yaml")) for d in cam_dirs]
        c0, c1 = cams
        if (c0.width, c0.height) != (c1.width, c1.height):
            raise InputError(cam_dirs[1] / "sensor.yaml", "cam1 resolution differs from cam0")
        size = (c0.width, c0.height)

        # Frames: stamps listed by both cameras. A stamp only one camera lists has no stereo twin and
        # is skipped with a warning (the bundled micro set's cam1 list names 4 such stamps); an image
        # that a stereo stamp needs but that is not on disk is an error naming the file.
        lists = [_read_image_list(d / "data.csv") for d in cam_dirs]
        stamps = [np.fromiter(lst, np.int64, count=len(lst)) for lst in lists]
        common = np.intersect1d(*stamps)
        for k, (d, other) in enumerate(((cam_dirs[0], cam_dirs[1]), (cam_dirs[1], cam_dirs[0]))):
            only = np.setdiff1d(stamps[k], common)
            if len(only):
                warn_input(d / "data.csv", f"{len(only)} stamp(s) have no image listed by {other.name} and are "
                                           f"skipped (first: {int(only[0])})")
        if not len(common):
            raise InputError(mav0, "no stereo pairs: no timestamp is listed by both cam0 and cam1")
        common = common[: truncate(max_frames, len(common), path)]
        pairs = [
            (s, cam_dirs[0] / "data" / lists[0][s], cam_dirs[1] / "data" / lists[1][s])
            for s in common.tolist()
        ]
        for s, *files in pairs:
            for f in files:
                if not f.is_file():
                    raise InputError(f, f"image listed in {f.parent.parent.name}/data.csv (stamp {s}) "
                                        f"is not on disk")
        pairs = pairs[: truncate(max_frames, len(pairs), path)]
        stamps_ns = np.array([p[0] for p in pairs], dtype=np.int64)

        # Rectification. OpenCV wants (R, T) taking cam0 points into cam1:
        # x1 = R x0 + T, i.e. T_c1_c0 = inv(T_c0_c1), T_c0_c1 = inv(T_B_c0) T_B_c1.
        T_c0_c1 = np.linalg.inv(c0.T_B_S) @ c1.T_B_S
        T_c1_c0 = np.linalg.inv(T_c0_c1)
        R1, R2, P1, P2, _Q, _roi1, _roi2 = cv2.stereoRectify(
            c0.K, c0.D, c1.K, c1.D, size, T_c1_c0[:3, :3].copy(), T_c1_c0[:3, 3].reshape(3, 1).copy(),
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
        )
        # Fixed-point maps are computed once; remap with them is ~2x faster than float maps.
        self._maps = [
            cv2.initUndistortRectifyMap(c.K, c.D, R, P, size, cv2.CV_16SC2)
            for c, R, P in ((c0, R1, P1), (c1, R2, P2))
        ]
        baseline = float(-P2[0, 3] / P2[0, 0])
        if not baseline > 0:
            raise InputError(mav0, f"rectified baseline is {baseline:g} m: cam1 is not to the right of cam0")
        calibration = StereoCalibration(
            fx=float(P1[0, 0]), fy=float(P1[1, 1]), cx=float(P1[0, 2]), cy=float(P1[1, 2]),
            baseline=baseline, width=size[0], height=size[1],
        )
        self.R_rect_left = R1  # rotates raw cam0 coordinates into the rectified left frame
        self.T_body_cam0 = c0.T_B_S

        stamps_s = _ns_to_seconds(stamps_ns)
        rate = c0.rate_hz
        if rate <= 0:
            rate = 1.0 / float(np.median(np.diff(stamps_s))) if len(stamps_s) > 1 else 20.0

        ground_truth = None
        gt_csv = mav0 / "state_groundtruth_estimate0" / "data.csv"
        if gt_csv.is_file():
            gt_ns, T_world_body = _read_groundtruth(gt_csv)
            fi, gi = nearest_match(stamps_ns, gt_ns, GT_TOLERANCE_NS)
            if len(fi):
                # Body pose -> raw cam0 -> rectified left (pure rotation R1^T).
                T_cam0_rect = np.eye(4)
                T_cam0_rect[:3, :3] = R1.T
                poses = T_world_body[gi] @ (c0.T_B_S @ T_cam0_rect)
                ground_truth = Trajectory(
                    stamps_s[fi], poses,
                    meta={"frame": "rectified left camera", "source": str(gt_csv),
                          "frame_indices": fi.tolist()},
                )

        super().__init__(
            name=f"euroc:{path.resolve().name}",
            root=path,
            calibration=calibration,
            rate_hz=rate,
            timestamps=stamps_s,
            left_paths=[p[1] for p in pairs],
            right_paths=[p[2] for p in pairs],
            ground_truth=ground_truth,
            rectifier=self._rectify,
        )

    def _rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        (l1, l2), (r1, r2) = self._maps
        return (
            cv2.remap(left, l1, l2, cv2.INTER_LINEAR),
            cv2.remap(right, r1, r2, cv2.INTER_LINEAR),
        )
