"""The supervisor's side of a run: gathers results and writes them out.

It receives every event the actors publish (poses, map snapshots, stats,
errors), prints a progress line, and at the end — normal or not — writes
whatever was computed: trajectories (TUM, readable by evo), the map as PLY,
metrics.json, stats.json and a trajectory plot, then returns the summary.

While the run goes, ``trajectory.tum`` and ``frames.csv`` grow a line per
frame (flushed), so even a SIGKILL of the launcher leaves the frames done so
far parseable; at the end the final files (poses re-expressed through the
bundle-adjusted keyframes) replace them atomically (``os.replace``).

Only frames with an estimated pose are in a trajectory: a lost frame's pose is
a placeholder, never written. ``frames.csv`` has a row for every frame of the
sequence and says why a frame has no pose (lost, dropped, not reached).
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from canopy.metrics import evaluate_trajectory
from canopy.report import plot_trajectory_png, write_json, write_ply_lines, write_ply_points
from canopy.trajectory_io import POSE_DECIMALS, TUM_TIME_DECIMALS, write_tum
from protocol.messages import ActorError, ActorStats, FramePose, LoopResult, MapSnapshot
from shared.geometry import rot_to_quat_wxyz
from shared.types import Trajectory

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"
FRAMES_COLUMNS = ["index", "timestamp", "status", "reason", "keyframe", "inliers", "matches", "enhance_method",
                  "mean_in", "mean_out", "enhance_ms", "orb_ms", "stereo_ms", "tracking_ms", "lines",
                  "line_inliers", "loop_candidate"]
# Statuses of frames that have an estimated pose (a "lost" frame's T_world_cam is a placeholder).
# "predicted": the tracker rejected its measurement and bridged with the motion model for a frame
# or two (written, since it is an estimate, but not counted as tracked).
POSED_STATUSES = ("init", "ok", "predicted")
TRACKED_STATUSES = ("init", "ok")
# Frames with no FramePose at all: skipped to keep up with the clock, or never reached.
STATUS_DROPPED, STATUS_NOT_REACHED = "dropped", "not_reached"
REASON_LOST_DEFAULT = "tracking lost"
REASON_DROPPED = "skipped by an actor to keep up with the realtime clock"
REASON_NOT_REACHED = "not reached: the run ended before this frame"


def has_pose(p: FramePose) -> bool:
    return p.status in POSED_STATUSES


def tum_line(stamp: float, T: np.ndarray) -> str:
    """One TUM row ``t x y z qx qy qz qw`` in the format of ``canopy.trajectory_io.write_tum``."""
    q = rot_to_quat_wxyz(np.asarray(T)[None, :3, :3])[0]
    vals = [*np.asarray(T)[:3, 3], q[1], q[2], q[3], q[0]]
    return f"{stamp:.{TUM_TIME_DECIMALS}f} " + " ".join(f"{v:.{POSE_DECIMALS}f}" for v in vals)


def _num(v) -> str:
    return "" if v is None else f"{float(v):.3f}"


def frame_row(p: FramePose, loop_candidate: int | None = None) -> str:
    e, t = p.enhancement, p.timings_ms
    reason = getattr(p, "lost_reason", "") or ("" if has_pose(p) else REASON_LOST_DEFAULT)
    return ",".join([str(p.index), f"{p.timestamp:.9f}", p.status, _csv_text(reason), str(int(p.is_keyframe)),
                     str(p.n_inliers), str(p.n_matches), _csv_text(str(e.get("method", ""))),
                     _num(e.get("mean_in")), _num(e.get("mean_out")), _num(t.get("enhance")),
                     _num(t.get("orb")), _num(t.get("stereo")), _num(t.get("total")),
                     str(p.n_lines), str(p.n_line_inliers), "" if loop_candidate is None else str(loop_candidate)])


def missing_row(index: int, stamp: float | None, status: str, reason: str) -> str:
    cells = [str(index), "" if stamp is None else f"{stamp:.9f}", status, _csv_text(reason)]
    return ",".join(cells + [""] * (len(FRAMES_COLUMNS) - len(cells)))


def _csv_text(text: str) -> str:
    return text.replace(",", ";").replace("\n", " ")


class IncrementalFiles:
    """``trajectory.tum`` and ``frames.csv`` written a line per frame as results arrive."""

    def __init__(self, out_dir: Path):
        self.trajectory_path = out_dir / "trajectory.tum"
        self.frames_path = out_dir / "frames.csv"
        # Line buffered: each line reaches the OS as soon as it is written, so a SIGKILL of the
        # launcher loses at most the line being written.
        self._traj = open(self.trajectory_path, "w", encoding="utf-8", buffering=1)
        self._frames = open(self.frames_path, "w", encoding="utf-8", buffering=1)
        self._traj.write(TUM_HEADER + "\n")
        self._frames.write(",".join(FRAMES_COLUMNS) + "\n")

    def add(self, p: FramePose) -> None:
        if self._traj is None:
            return
        if has_pose(p):
            self._traj.write(tum_line(p.timestamp, p.T_world_cam) + "\n")
        self._frames.write(frame_row(p) + "\n")

    def close(self) -> None:
        for fh in (self._traj, self._frames):
            if fh is not None:
                fh.close()
        self._traj = self._frames = None


def replace_atomically(path: Path, write) -> Path:
    """``write(tmp_path)`` then rename over ``path``: a reader sees the old or the new file, whole."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)
    return path

ACTOR_ORDER = ("source", "enhancement", "tracking", "local_mapping", "loop_closing")


@dataclass
class ActorRecord:
    service_ms: list = field(default_factory=list)
    queue_ms: list = field(default_factory=list)
    messages: int = 0
    dropped: int = 0
    cpu: list = field(default_factory=list)
    rss_mb: float = 0.0
    peak_rss_mb: float = 0.0
    extra: dict = field(default_factory=dict)

    def summary(self) -> dict:
        s = np.asarray(self.service_ms, np.float64)
        q = np.asarray(self.queue_ms, np.float64)
        cpu = np.asarray(self.cpu, np.float64)

        def pct(a, p):
            return float(np.percentile(a, p)) if len(a) else None

        return {"messages": self.messages, "dropped": self.dropped,
                "service_ms": {"p50": pct(s, 50), "p95": pct(s, 95), "p99": pct(s, 99),
                               "max": float(s.max()) if len(s) else None,
                               "mean": float(s.mean()) if len(s) else None},
                "queue_ms": {"p50": pct(q, 50), "p95": pct(q, 95), "p99": pct(q, 99),
                             "max": float(q.max()) if len(q) else None},
                # the first sample covers start-up imports; the run's load is the rest
                "cpu_percent": {"mean": float(cpu[1:].mean()) if len(cpu) > 1 else (float(cpu[0]) if len(cpu) else None),
                                "max": float(cpu.max()) if len(cpu) else None},
                "rss_mb": self.rss_mb, "peak_rss_mb": self.peak_rss_mb, "extra": self.extra}


class RunCollector:
    def __init__(self, n_frames: int, progress: bool = True, stream=sys.stderr, out_dir: Path | None = None,
                 frame_stamps=None, first_index: int = 0):
        self.n_frames = n_frames
        self.first_index = int(first_index)  # a run extending a loaded map numbers frames after its keyframes
        self.frame_stamps = None if frame_stamps is None else np.asarray(frame_stamps, np.float64)
        self.incremental = IncrementalFiles(Path(out_dir)) if out_dir is not None else None
        self.poses: dict[int, FramePose] = {}
        self.snapshot: MapSnapshot | None = None
        self.actors: dict[str, ActorRecord] = {}
        self.errors: list[ActorError] = []
        self.loops: list[LoopResult] = []  # closed loops, in the order the loop closer found them
        self.progress = progress
        self.stream = stream
        self._last_print = 0.0
        self._t0 = time.monotonic()
        self._first_pose_t: float | None = None

    # -- events --------------------------------------------------------------------------
    def __call__(self, msg) -> None:
        if isinstance(msg, FramePose):
            if self._first_pose_t is None:
                self._first_pose_t = time.monotonic()
            self.poses[msg.index] = msg
            if self.incremental is not None:
                self.incremental.add(msg)
            self._print_progress()
        elif isinstance(msg, MapSnapshot):
            self.snapshot = msg
        elif isinstance(msg, ActorStats):
            rec = self.actors.setdefault(msg.actor, ActorRecord())
            rec.service_ms.extend(np.asarray(msg.service_ms).tolist())
            rec.queue_ms.extend(np.asarray(msg.queue_ms).tolist())
            rec.messages = msg.messages
            rec.dropped = msg.dropped
            if not msg.final or not rec.cpu:
                rec.cpu.append(msg.cpu_percent)
            rec.rss_mb = msg.rss_mb
            rec.peak_rss_mb = max(rec.peak_rss_mb, msg.peak_rss_mb)
            rec.extra.update(msg.extra)
        elif isinstance(msg, ActorError):
            self.errors.append(msg)
        elif isinstance(msg, LoopResult) and msg.closed:
            self.loops.append(msg)

    def _print_progress(self, force: bool = False) -> None:
        now = time.monotonic()
        tty = self.stream.isatty()
        # A terminal gets a live line; a log file gets a line every few seconds.
        if not self.progress or (not force and now - self._last_print < (0.25 if tty else 5.0)):
            return
        self._last_print = now
        n = len(self.poses)
        lost = sum(not has_pose(p) for p in self.poses.values())
        kfs = sum(p.is_keyframe for p in self.poses.values())
        fps = n / max(now - (self._first_pose_t or now), 1e-6) if n > 1 else 0.0
        line = f"  frame {n:5d}/{self.n_frames}  keyframes {kfs:4d}  lost {lost:4d}  {fps:6.1f} fps "
        self.stream.write(f"\r{line}" if tty else f"{line}\n")
        self.stream.flush()

    def finish_progress(self) -> None:
        if self.progress and self.poses:
            self._print_progress(force=True)
            if self.stream.isatty():
                self.stream.write("\n")

    # -- trajectories --------------------------------------------------------------------
    def keyframe_trajectory(self) -> Trajectory:
        if self.snapshot is None or len(self.snapshot.keyframe_indices) == 0:
            kf = [p for _, p in sorted(self.poses.items()) if p.is_keyframe and has_pose(p)]
            return Trajectory([p.timestamp for p in kf], np.array([p.T_world_cam for p in kf]).reshape(-1, 4, 4))
        order = np.argsort(self.snapshot.keyframe_indices)
        return Trajectory(self.snapshot.keyframe_stamps[order], self.snapshot.keyframe_poses[order])

    def camera_trajectory(self) -> Trajectory:
        """Every frame's pose, re-expressed through its (possibly corrected) reference keyframe."""
        corrected: dict[int, np.ndarray] = {}
        if self.snapshot is not None:
            corrected = {int(i): T for i, T in zip(self.snapshot.keyframe_indices, self.snapshot.keyframe_poses)}
        stamps, poses = [], []
        for idx in sorted(self.poses):
            p = self.poses[idx]
            if not has_pose(p):
                continue  # no estimate: a placeholder pose would be a fabricated one
            T_w_ref = corrected.get(int(p.ref_keyframe))
            poses.append(T_w_ref @ p.T_ref_cam if T_w_ref is not None else p.T_world_cam)
            stamps.append(p.timestamp)
        return Trajectory(stamps, np.array(poses).reshape(-1, 4, 4))

    # -- outputs -------------------------------------------------------------------------
    def frame_rows(self, run_ended_early: bool) -> list[str]:
        """One row per frame of the sequence: tracking outcome, enhancement decision and timings,
        and for a frame without a pose, why (lost / dropped / not reached)."""
        rows = [",".join(FRAMES_COLUMNS)]
        first = self.first_index
        last = max(self.poses, default=first - 1)
        loop_at = {int(lp.keyframe_index): int(lp.candidate) for lp in self.loops}  # keyframe closing a loop -> place
        for idx in range(first, max(first + self.n_frames, last + 1)):
            p = self.poses.get(idx)
            if p is not None:
                rows.append(frame_row(p, loop_at.get(idx)))
                continue
            stamp = float(self.frame_stamps[idx - first]) if self.frame_stamps is not None and idx - first < len(
                self.frame_stamps) else None
            if idx > last and run_ended_early:
                rows.append(missing_row(idx, stamp, STATUS_NOT_REACHED, REASON_NOT_REACHED))
            else:
                rows.append(missing_row(idx, stamp, STATUS_DROPPED, REASON_DROPPED))
        return rows

    def write_frames_csv(self, path: Path, run_ended_early: bool = False) -> Path:
        rows = self.frame_rows(run_ended_early)
        return replace_atomically(path, lambda tmp: tmp.write_text("\n".join(rows) + "\n"))

    def tracking_summary(self, run_ended_early: bool = False) -> dict:
        """Counts over the whole sequence: a dropped or lost frame counts against success."""
        rows = self.frame_rows(run_ended_early)[1:]
        status = [r.split(",", 3)[2] for r in rows]
        total = max(self.n_frames, len(rows))
        tracked = sum(s in TRACKED_STATUSES for s in status)
        n = len(self.poses)
        return {"frames_total": total, "frames_processed": n, "frames_tracked": tracked,
                "frames_predicted": status.count("predicted"), "frames_lost": status.count("lost"), "frames_dropped": status.count(STATUS_DROPPED),
                "frames_not_reached": status.count(STATUS_NOT_REACHED),
                "keyframes": int(sum(p.is_keyframe for p in self.poses.values())),
                "tracking_success_percent": 100.0 * tracked / total if total else 0.0,
                "coverage_percent": 100.0 * n / total if total else 0.0}

    def latency_summary(self) -> dict:
        """End-to-end latency, frame read by the source -> pose published by tracking (ms), over the
        frames in index order; the first and last thirds tell a latency that keeps growing (an actor
        that cannot keep up) from a steady one (benchmarks/bench_load.py)."""
        rows = [(i, p) for i, p in sorted(self.poses.items()) if p.frame_read_at > 0 and p.sent_at > 0]
        e2e = np.array([(p.sent_at - p.frame_read_at) * 1e3 for _, p in rows], np.float64)
        if not len(e2e):
            return {"n": 0}
        third = max(1, len(e2e) // 3)
        sent = np.array([p.sent_at for _, p in rows])
        span = float(sent.max() - sent.min())
        return {"n": int(len(e2e)),
                # poses per second while poses flow (a run's wall time also holds actor start-up)
                "pose_rate_hz": (len(e2e) - 1) / span if span > 0 else None, "p50": float(np.percentile(e2e, 50)), "p95": float(np.percentile(e2e, 95)),
                "p99": float(np.percentile(e2e, 99)), "max": float(e2e.max()),
                "first_third_p95": float(np.percentile(e2e[:third], 95)),
                "last_third_p95": float(np.percentile(e2e[-third:], 95))}

    def stats_summary(self) -> dict:
        names = sorted(self.actors, key=lambda a: ACTOR_ORDER.index(a) if a in ACTOR_ORDER else 99)
        return {name: self.actors[name].summary() for name in names}

    def write_outputs(self, out_dir: Path, gt: Trajectory | None, run_info: dict) -> dict:
        out_dir.mkdir(parents=True, exist_ok=True)
        if self.incremental is not None:
            self.incremental.close()
        early = not run_info.get("ok", True)
        cam = self.camera_trajectory()
        kfs = self.keyframe_trajectory()
        files = {}
        if len(cam):
            files["trajectory"] = str(replace_atomically(out_dir / "trajectory.tum", lambda tmp: write_tum(tmp, cam)))
        elif (out_dir / "trajectory.tum").exists():
            (out_dir / "trajectory.tum").unlink()  # only the header was written: no frame has a pose
        if len(kfs):
            files["keyframes"] = str(write_tum(out_dir / "keyframes.tum", kfs))
        points = self.snapshot.points if self.snapshot is not None else np.zeros((0, 3), np.float32)
        files["map_points"] = str(write_ply_points(out_dir / "map_points.ply", np.asarray(points, np.float64)))
        lines = self.snapshot.lines if self.snapshot is not None else np.zeros((0, 2, 3), np.float32)
        if len(lines):
            files["map_lines"] = str(write_ply_lines(out_dir / "map_lines.ply", np.asarray(lines, np.float64)))
        files["frames"] = str(self.write_frames_csv(out_dir / "frames.csv", run_ended_early=early))
        metrics = evaluate_trajectory(cam, gt) if len(cam) else {"note": "no frame was tracked"}
        metrics["tracking"] = self.tracking_summary(run_ended_early=early)
        metrics["end_to_end_ms"] = self.latency_summary()
        metrics["map_points"] = int(len(points))
        metrics["map_lines"] = int(len(lines))
        metrics["run"] = run_info
        metrics["loops"] = {"closed": len(self.loops),
                            "pairs": [{"keyframe": int(lp.keyframe_index), "candidate": int(lp.candidate),
                                       "inliers": int(lp.n_inliers)} for lp in self.loops]}
        files["metrics"] = str(write_json(out_dir / "metrics.json", metrics))
        stats = self.stats_summary()
        files["stats"] = str(write_json(out_dir / "stats.json", stats))
        if len(cam) >= 2:
            try:
                title = f"{run_info.get('source', '')} ({run_info.get('clock', '')})"
                align = "sim3" if run_info.get("sensor") == "mono" else "se3"  # a mono map has no metric scale
                files["plot"] = str(plot_trajectory_png(out_dir / "trajectory.png", cam, gt, title=title, align=align))
            except Exception as exc:  # a plot must never cost the user the numbers
                files["plot_error"] = f"{type(exc).__name__}: {exc}"
        return {"metrics": metrics, "stats": stats, "files": files}


def format_summary(summary: dict, outcome_reason: str, n_cores: int) -> str:
    m = summary["metrics"]
    t = m["tracking"]
    lines = ["", "Canopy SLAM — run summary", "=" * 72,
             f"  outcome              {outcome_reason}",
             f"  frames               {t['frames_processed']}/{t['frames_total']} processed, "
             f"{t['keyframes']} keyframes, {t['frames_lost']} lost, {t.get('frames_dropped', 0)} dropped"
             + (f", {t['frames_not_reached']} not reached" if t.get("frames_not_reached") else ""),
             f"  tracking success     {t['tracking_success_percent']:.1f} % "
             f"({t.get('frames_tracked', 0)} of {t['frames_total']} frames have a pose)",
             f"  map                  {m.get('map_points', 0)} points, {m.get('map_lines', 0)} line segments"]
    ate = m.get("ate")
    if ate and ate.get("rmse") is not None:
        lines.append(f"  ATE (SE3-aligned)    rmse {ate['rmse']:.4f} m   max {ate['max']:.4f} m   (n={ate['n']})")
    sim3 = m.get("ate_sim3")
    if sim3 and sim3.get("rmse") is not None and (m.get("run") or {}).get("sensor") == "mono":
        lines.append(f"  ATE (Sim3-aligned)   rmse {sim3['rmse']:.4f} m   scale {sim3.get('scale', float('nan')):.4f}")
    rpe_f = m.get("rpe_frame")
    if rpe_f and rpe_f.get("rmse") is not None:
        lines.append(f"  RPE per frame        rmse {rpe_f['rmse']:.4f} m   rot {rpe_f.get('rot_rmse', float('nan')):.3f} deg")
    rpe_m = m.get("rpe_metre")
    if rpe_m and rpe_m.get("rmse") is not None:
        lines.append(f"  RPE per metre        rmse {rpe_m['rmse']:.4f} m   rot {rpe_m.get('rot_rmse', float('nan')):.3f} deg")
    kitti = m.get("kitti") or {}
    if kitti.get("t_rel_percent") is not None:
        lines.append(f"  KITTI t_rel / r_rel  {kitti['t_rel_percent']:.2f} %   {kitti['r_rel_deg_per_100m']:.3f} deg/100m "
                     f"(segments of {', '.join(f'{x:.1f}' for x in kitti.get('lengths_used') or [])} m)")
    em = m.get("est_motion")
    if em:
        lines.append(f"  estimated motion     {em['translation_m']:.4f} m, {em['rotation_deg']:.3f} deg "
                     f"(path {em['path_length_m']:.3f} m)")
    loops = m.get("loops") or {}
    if "loop_closing" in (m.get("run") or {}) or loops.get("closed"):
        lines.append(f"  loops closed         {loops.get('closed', 0)}")
    if m.get("note"):
        lines.append(f"  note                 {m['note']}")
    errors = (m.get("run") or {}).get("errors") or []
    if errors:
        first = errors[0]
        lines.append(f"  problems             {len(errors)} reported; first: {first['actor']}: {first['error']}")
    lines += ["", f"  per actor ({n_cores} cores)     msgs  drop  svc p50   p95     max  | queue p50  | CPU %  | peak RSS",
              "  " + "-" * 98]
    for name, s in summary["stats"].items():
        sv, qu = s["service_ms"], s["queue_ms"]

        def f(v, w=7, d=1):
            return f"{v:{w}.{d}f}" if v is not None else " " * (w - 1) + "-"

        cpu = s["cpu_percent"]["mean"]
        lines.append(f"  {name:18s} {s['messages']:7d} {s['dropped']:5d} {f(sv['p50'])} {f(sv['p95'])} {f(sv['max'])} "
                     f"| {f(qu['p50'], 9)}  | {f(cpu, 6)} | {s['peak_rss_mb']:6.0f} MB")
    lines.append("")
    lines.append("  outputs:")
    for key, path in summary["files"].items():
        lines.append(f"    {key:12s} {path}")
    return "\n".join(lines)
