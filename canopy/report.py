"""Files a run leaves behind: map PLYs, metrics JSON, trajectory plot PNG.

PLY files follow the Stanford PLY layout that Open3D, CloudCompare and
MeshLab read: ``vertex`` with float x/y/z (+ uchar red/green/blue), and for
line maps an ``edge`` element with int vertex1/vertex2.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from shared.types import Trajectory

from canopy import metrics

PLOT_DPI = 110
PLOT_SIZE_IN = (12.0, 5.5)


# --------------------------------------------------------------------------- PLY

def _ply_header(n_vertex: int, with_color: bool, n_edge: int | None, binary: bool,
                comment: str) -> bytes:
    fmt = "binary_little_endian" if binary else "ascii"
    lines = ["ply", f"format {fmt} 1.0"]
    if comment:
        lines.append(f"comment {comment}")
    lines += [f"element vertex {n_vertex}", "property float x", "property float y",
              "property float z"]
    if with_color:
        lines += ["property uchar red", "property uchar green", "property uchar blue"]
    if n_edge is not None:
        lines += [f"element edge {n_edge}", "property int vertex1", "property int vertex2"]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply_points(path, xyz, colors=None, binary: bool = True,
                     comment: str = "Canopy SLAM map points") -> Path:
    """Point cloud PLY. ``xyz`` (N, 3); ``colors`` (N, 3) uint8 RGB or None.

    Non-finite points are dropped (with their colours).
    """
    path = Path(path)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    keep = np.all(np.isfinite(xyz), axis=1)
    xyz = xyz[keep].astype("<f4")
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (len(keep), 3):
            raise ValueError(f"colors must be ({len(keep)}, 3), got {colors.shape}")
        colors = np.clip(colors, 0, 255).astype(np.uint8)[keep]
    path.parent.mkdir(parents=True, exist_ok=True)
    header = _ply_header(len(xyz), colors is not None, None, binary, comment)
    with open(path, "wb") as fh:
        fh.write(header)
        if binary:
            if colors is None:
                fh.write(xyz.tobytes())
            else:
                rec = np.empty(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                                ("r", "u1"), ("g", "u1"), ("b", "u1")])
                rec["x"], rec["y"], rec["z"] = xyz.T
                rec["r"], rec["g"], rec["b"] = colors.T
                fh.write(rec.tobytes())
        else:
            for i, p in enumerate(xyz):
                row = f"{p[0]:.7g} {p[1]:.7g} {p[2]:.7g}"
                if colors is not None:
                    row += f" {colors[i, 0]} {colors[i, 1]} {colors[i, 2]}"
                fh.write((row + "\n").encode("ascii"))
    return path


def write_ply_lines(path, endpoints, binary: bool = True,
                    comment: str = "Canopy SLAM map line segments") -> Path:
    """Line-segment PLY: 2N vertices (the endpoints) and N edges (2i, 2i+1).

    ``endpoints`` is (N, 2, 3). Segments with a non-finite endpoint are dropped.
    """
    path = Path(path)
    ep = np.asarray(endpoints, dtype=np.float64).reshape(-1, 2, 3)
    ep = ep[np.all(np.isfinite(ep), axis=(1, 2))]
    verts = ep.reshape(-1, 3).astype("<f4")
    n = len(ep)
    edges = np.arange(2 * n, dtype="<i4").reshape(n, 2)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        fh.write(_ply_header(len(verts), False, n, binary, comment))
        if binary:
            fh.write(verts.tobytes())
            fh.write(edges.tobytes())
        else:
            for p in verts:
                fh.write(f"{p[0]:.7g} {p[1]:.7g} {p[2]:.7g}\n".encode("ascii"))
            for e in edges:
                fh.write(f"{e[0]} {e[1]}\n".encode("ascii"))
    return path


# --------------------------------------------------------------------------- JSON

def to_jsonable(obj):
    """Plain JSON values: numpy scalars and arrays become numbers and lists, NaN/inf become
    null (JSON has none; Foxglove's JSON.parse rejects them), paths and unknowns strings."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    return str(obj)


def write_json(path, obj, indent: int = 2) -> Path:
    """JSON file of ``obj``; numpy scalars/arrays become plain numbers/lists,
    NaN and inf become null."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(to_jsonable(obj), fh, indent=indent, allow_nan=False)
        fh.write("\n")
    return path


# --------------------------------------------------------------------------- plot

def top_view_axes(poses: np.ndarray) -> tuple[int, int]:
    """The two world axes of a view from above. A camera's y axis points down (OpenCV
    convention), so the world axis closest to the cameras' mean y direction is the vertical and
    the other two span the ground plane: x-z for KITTI and for any run's own first-camera frame,
    x-y for EuRoC's gravity-aligned (z up) ground truth."""
    poses = np.asarray(poses).reshape(-1, 4, 4)
    if not len(poses):
        return 0, 2
    down = poses[:, :3, 1].mean(axis=0)
    vertical = int(np.argmax(np.abs(down)))
    a, b = [k for k in range(3) if k != vertical]
    return a, b


PLOT_ALIGNMENTS = ("se3", "sim3")


def align_for_plot(est: Trajectory, gt: Trajectory | None, align: str = "se3",
                   max_diff: float = 0.01) -> tuple[np.ndarray, str, str]:
    """Positions of ``est`` as drawn beside ``gt``: (positions (N, 3), legend label, ATE text).

    ``align`` "se3" (stereo: metric map, evo ``-a``) or "sim3" (monocular: the map has no
    metric scale, evo ``-as``; Umeyama 1991 with scale). The alignment is fitted on the stamps
    matched within ``max_diff`` s and applied to every pose; with Sim(3) the fitted scale
    (metres per map unit) is printed in the label and the ATE text, because it is part of the
    result of a monocular run (its drift is reported, not hidden). No ``gt``: positions as they are.
    """
    if align not in PLOT_ALIGNMENTS:
        raise ValueError(f"plot alignment must be one of {PLOT_ALIGNMENTS}, got {align!r}")
    est_pos = est.positions.copy()
    if gt is None or not len(gt) or not len(est):
        return est_pos, "estimate", ""
    ia, ib = metrics.associate(est.stamps, gt.stamps, max_diff)
    if len(ia) < 1:
        return est_pos, "estimate", f"ATE: no stamps matched within {max_diff} s"
    if align == "sim3":
        ate = metrics.ate_sim3(est.poses[ia], gt.poses[ib])
        if ate.get("scale") is None:  # < 3 poses or no motion: a scale cannot be fitted
            return est_pos, "estimate", f"ATE: Sim(3) alignment needs motion ({ate['n']} poses)"
        R, t, s = metrics.umeyama_alignment(est.positions[ia].T, gt.positions[ib].T, with_scale=True)
        scale_text = f"scale {s:.4g} m/unit"
        return (s * est.positions @ R.T + t, f"estimate (Sim(3) aligned, {scale_text})",
                f"ATE RMSE {ate['rmse']:.4f} m (Sim(3) aligned, {scale_text}, {ate['n']} poses)")
    R, t, _ = metrics.umeyama_alignment(est.positions[ia].T, gt.positions[ib].T)
    ate = metrics.ape(est.poses[ia], gt.poses[ib], align="se3")
    return (est.positions @ R.T + t, "estimate (SE(3) aligned)",
            f"ATE RMSE {ate['rmse']:.4f} m (SE(3) aligned, {ate['n']} poses)")


def plot_trajectory_png(path, est: Trajectory, gt: Trajectory | None = None, title: str = "",
                        max_diff: float = 0.01, align: str = "se3") -> Path:
    """Top view and x/y/z against time of ``est`` (and ``gt``).

    With ``gt``, ``est`` is aligned to it (``align_for_plot``: SE(3), or Sim(3) with the scale
    in the legend and title for a monocular run) on the stamps matched within ``max_diff`` s
    and the title carries the ATE RMSE. The top view looks along the vertical
    (``top_view_axes``, of gt when given, else est): x-z for camera frames (y down).
    Headless (Agg backend).
    """
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    est_pos, label_est, ate_text = align_for_plot(est, gt, align, max_diff)
    a, b = top_view_axes(gt.poses if gt is not None and len(gt) else est.poses)
    names = "xyz"

    fig = plt.figure(figsize=PLOT_SIZE_IN, dpi=PLOT_DPI)
    try:
        ax_top = fig.add_subplot(1, 2, 1)
        if gt is not None and len(gt):
            ax_top.plot(gt.positions[:, a], gt.positions[:, b], "k--", lw=1.2, label="ground truth")
        if len(est_pos):
            ax_top.plot(est_pos[:, a], est_pos[:, b], "-", color="tab:blue", lw=1.2, label=label_est)
            ax_top.plot(est_pos[0, a], est_pos[0, b], "o", color="tab:green", label="start")
        ax_top.set_xlabel(f"{names[a]} [m]")
        ax_top.set_ylabel(f"{names[b]} [m]")
        ax_top.set_aspect("equal", adjustable="datalim")
        ax_top.grid(True, alpha=0.3)
        ax_top.legend(loc="best", fontsize=8)
        ax_top.set_title(f"top view ({names[a]}-{names[b]})")

        t0 = min([s[0] for s in (est.stamps, gt.stamps if gt is not None else np.zeros(0)) if len(s)],
                 default=0.0)
        for k in range(3):
            ax = fig.add_subplot(3, 2, 2 * k + 2)
            if gt is not None and len(gt):
                ax.plot(gt.stamps - t0, gt.positions[:, k], "k--", lw=1.0)
            if len(est_pos):
                ax.plot(est.stamps - t0, est_pos[:, k], "-", color="tab:blue", lw=1.0)
            ax.set_ylabel(f"{names[k]} [m]")
            ax.grid(True, alpha=0.3)
            if k == 2:
                ax.set_xlabel("time since start [s]")
        full_title = " | ".join(s for s in (title, ate_text) if s)
        if full_title:
            fig.suptitle(full_title)
        fig.tight_layout()
        fig.savefig(path)
    finally:
        plt.close(fig)
    return path
