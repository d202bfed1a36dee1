"""Trajectory files: TUM, KITTI poses, EuRoC ground-truth CSV.

- TUM: ``t x y z qx qy qz qw`` per line, ``#`` comments (what ``evo`` reads).
- KITTI: 12 numbers per line, the row-major top 3x4 of each pose; no stamps in
  the file (optionally ``times.txt`` beside it).
- EuRoC ASL ``data.csv`` of ``state_groundtruth_estimate0`` (and the
  ``leica``/``vicon`` style files): ``#timestamp [ns], p_RS_R_x, p_RS_R_y,
  p_RS_R_z, q_RS_w, q_RS_x, q_RS_y, q_RS_z, ...``; only the first 8 columns
  are used, nanoseconds become seconds. The pose is T_world_body (IMU body),
  not the camera: ``meta["frame"]`` says so.

Quaternions are Hamilton, unit (inputs are normalised). A malformed row raises
:class:`shared.errors.InputError` naming the file and the line number.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from shared.errors import InputError
from shared.types import Trajectory

TUM_TIME_DECIMALS = 9
POSE_DECIMALS = 9
_SPLIT = re.compile(r"[,\s]+")


from shared.geometry import poses_from_xyz_quat_wxyz, quat_wxyz_to_rot, rot_to_quat_wxyz  # noqa: F401 (re-export)


def _read_rows(path: Path, ncols: int, what: str, min_cols: int | None = None,
               raw_text: bool = False) -> tuple[list[list], list[int]]:
    """Numeric rows of a text file, skipping blanks and ``#`` comments.

    Each row must have exactly ``ncols`` fields (at least ``min_cols`` when
    given; then only the first ``ncols`` are kept). Returns rows (floats, or
    the checked field strings with ``raw_text``) and their 1-based line numbers.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, f"{what} file not found")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read {what} file: {exc}") from None
    rows, lines = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = [f for f in _SPLIT.split(s) if f]
        if min_cols is None and len(fields) != ncols:
            raise InputError(path, f"line {lineno}: expected {ncols} numbers for {what}, "
                                   f"found {len(fields)}: {s[:80]!r}")
        if min_cols is not None and len(fields) < min_cols:
            raise InputError(path, f"line {lineno}: expected at least {min_cols} columns for "
                                   f"{what}, found {len(fields)}: {s[:80]!r}")
        try:
            numbers = [float(f) for f in fields[:ncols]]
        except ValueError:
            raise InputError(path, f"line {lineno}: not a number in {s[:80]!r}") from None
        if not all(np.isfinite(v) for v in numbers):
            raise InputError(path, f"line {lineno}: non-finite value in {s[:80]!r}")
        rows.append(numbers if raw_text is False else fields[:ncols])
        lines.append(lineno)
    if not rows:
        raise InputError(path, f"no {what} rows found")
    return rows, lines


def _poses_checked(path: Path, xyz, q, lines) -> np.ndarray:
    norms = np.linalg.norm(np.asarray(q, dtype=np.float64), axis=1)
    bad = np.flatnonzero(norms < 1e-12)
    if bad.size:
        raise InputError(path, f"line {lines[bad[0]]}: quaternion has zero norm")
    return poses_from_xyz_quat_wxyz(xyz, q)


def read_tum(path) -> Trajectory:
    """TUM trajectory ``t x y z qx qy qz qw`` -> Trajectory (meta: source, format)."""
    path = Path(path)
    rows, lines = _read_rows(path, 8, "TUM trajectory")
    a = np.asarray(rows, dtype=np.float64)
    q_wxyz = a[:, [7, 4, 5, 6]]
    poses = _poses_checked(path, a[:, 1:4], q_wxyz, lines)
    return Trajectory(a[:, 0], poses, meta={"source": str(path), "format": "tum"})


def write_tum(path, traj: Trajectory) -> Path:
    """Write ``t x y z qx qy qz qw`` with 9 decimals (readable by evo)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    q = rot_to_quat_wxyz(traj.poses[:, :3, :3]) if len(traj) else np.zeros((0, 4))
    p = traj.positions
    t_fmt = f"{{:.{TUM_TIME_DECIMALS}f}}"
    v_fmt = f"{{:.{POSE_DECIMALS}f}}"
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("# timestamp tx ty tz qx qy qz qw\n")
        for t, xyz, qq in zip(traj.stamps, p, q):
            vals = [*xyz, qq[1], qq[2], qq[3], qq[0]]
            fh.write(t_fmt.format(t) + " " + " ".join(v_fmt.format(v) for v in vals) + "\n")
    return path


def read_kitti(path, times=None) -> Trajectory:
    """KITTI poses (12 numbers per line) -> Trajectory.

    ``times`` is a path to a KITTI ``times.txt`` (one stamp per line) or an
    array of stamps; without it the stamps are the frame indices 0, 1, 2, ...
    """
    path = Path(path)
    rows, _ = _read_rows(path, 12, "KITTI pose")
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 3, 4)
    poses = np.tile(np.eye(4), (len(a), 1, 1))
    poses[:, :3, :] = a
    if times is None:
        stamps = np.arange(len(a), dtype=np.float64)
    elif isinstance(times, (str, Path)):
        trows, _ = _read_rows(Path(times), 1, "KITTI times")
        stamps = np.asarray(trows, dtype=np.float64).reshape(-1)
    else:
        stamps = np.asarray(times, dtype=np.float64).reshape(-1)
    if len(stamps) != len(poses):
        raise InputError(times if isinstance(times, (str, Path)) else path,
                         f"{len(stamps)} timestamps for {len(poses)} poses in {path}")
    return Trajectory(stamps, poses, meta={"source": str(path), "format": "kitti"})


def write_kitti(path, traj: Trajectory) -> Path:
    """Write the 12 top 3x4 numbers of each pose per line (no stamps)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    flat = traj.poses[:, :3, :].reshape(-1, 12)
    np.savetxt(path, flat, fmt=f"%.{POSE_DECIMALS}e")
    return path


def _parse_ns(field: str) -> int:
    """Integer nanoseconds; a float spelling (``1.4e18``) is accepted."""
    try:
        return int(field)
    except ValueError:
        return int(float(field))


def read_euroc_csv(path) -> Trajectory:
    """EuRoC ground-truth CSV -> Trajectory of T_world_body, stamps in seconds."""
    path = Path(path)
    rows, lines = _read_rows(path, 8, "EuRoC ground-truth", min_cols=8, raw_text=True)
    ns = np.empty(len(rows), dtype=np.int64)
    for k, (r, ln) in enumerate(zip(rows, lines)):
        try:
            ns[k] = _parse_ns(r[0])
        except (ValueError, OverflowError):
            raise InputError(path, f"line {ln}: timestamp {r[0]!r} is not in integer "
                                   "nanoseconds") from None
    a = np.asarray([[float(v) for v in r[1:]] for r in rows], dtype=np.float64)
    # Split the integer nanoseconds so the seconds keep full float64 precision.
    stamps = (ns // 1_000_000_000).astype(np.float64) + (ns % 1_000_000_000).astype(np.float64) * 1e-9
    poses = _poses_checked(path, a[:, 0:3], a[:, 3:7], lines)
    return Trajectory(stamps, poses, meta={"source": str(path), "format": "euroc",
                                           "frame": "T_world_body"})


def read_trajectory(path, fmt: str = "auto", times=None) -> Trajectory:
    """Read any of the three formats; ``fmt`` "tum", "kitti", "euroc" or "auto".

    "auto": ``.csv`` is EuRoC; otherwise the first data row decides
    (8 numbers TUM, 12 numbers KITTI).
    """
    path = Path(path)
    if fmt == "auto":
        if path.suffix.lower() == ".csv":
            fmt = "euroc"
        else:
            if not path.is_file():
                raise InputError(path, "trajectory file not found")
            fmt = None
            with open(path, encoding="utf-8", errors="replace") as fh:
                for line in fh:
                    s = line.strip()
                    if s and not s.startswith("#"):
                        n = len([f for f in _SPLIT.split(s) if f])
                        fmt = {8: "tum", 12: "kitti"}.get(n)
                        if fmt is None:
                            raise InputError(path, f"cannot tell the trajectory format from a "
                                                   f"row of {n} numbers (TUM has 8, KITTI 12)")
                        break
            if fmt is None:
                raise InputError(path, "no trajectory rows found")
    if fmt == "tum":
        return read_tum(path)
    if fmt == "kitti":
        return read_kitti(path, times)
    if fmt == "euroc":
        return read_euroc_csv(path)
    raise InputError(path, f"unknown trajectory format {fmt!r} (tum, kitti, euroc)")
