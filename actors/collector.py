"""The supervisor's side of a run: gathers results and writes them out.

It receives every event the actors publish (poses, map snapshots, stats,
errors), prints a progress line, and at the end — normal or not — writes
whatever was computed: trajectories (TUM, readable by evo), the map as PLY,
metrics.json, stats.json and a trajectory plot, then returns the summary.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from canopy.metrics import evaluate_trajectory
from canopy.report import plot_trajectory_png, write_json, write_ply_lines, write_ply_points
from canopy.trajectory_io import write_tum
from protocol.messages import ActorError, ActorStats, FramePose, LoopResult, MapSnapshot
from shared.types import Trajectory

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
                "service_ms": {"p50": pct(s, 50), "p95": pct(s, 95), "max": float(s.max()) if len(s) else None,
                               "mean": float(s.mean()) if len(s) else None},
                "queue_ms": {"p50": pct(q, 50), "p95": pct(q, 95), "max": float(q.max()) if len(q) else None},
                # the first sample covers start-up imports; the run's load is the rest
                "cpu_percent": {"mean": float(cpu[1:].mean()) if len(cpu) > 1 else (float(cpu[0]) if len(cpu) else None),
                                "max": float(cpu.max()) if len(cpu) else None},
                "rss_mb": self.rss_mb, "peak_rss_mb": self.peak_rss_mb, "extra": self.extra}


class RunCollector:
    def __init__(self, n_frames: int, progress: bool = True, stream=sys.stderr):
        self.n_frames = n_frames
        self.poses: dict[int, FramePose] = {}
        self.snapshot: MapSnapshot | None = None
        self.actors: dict[str, ActorRecord] = {}
        self.errors: list[ActorError] = []
        self.progress = progress
        self.stream = stream
        self._last_print = 0.0
        self._t0 = time.monotonic()
        self._first_pose_t: float | None = None
        self.loops: list[LoopResult] = []  # closed loops, in the order the loop closer found them

    # -- events --------------------------------------------------------------------------
    def __call__(self, msg) -> None:
        if isinstance(msg, FramePose):
            if self._first_pose_t is None:
                self._first_pose_t = time.monotonic()
            self.poses[msg.index] = msg
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
        lost = sum(p.status == "lost" for p in self.poses.values())
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
            kf = [p for _, p in sorted(self.poses.items()) if p.is_keyframe]
            return Trajectory([p.timestamp for p in kf], np.array([p.T_world_cam for p in kf]).reshape(-1, 4, 4))
        order = np.argsort(self.snapshot.keyframe_indices)
        return Trajectory(self.snapshot.keyframe_stamps[order], self.snapshot.keyframe_poses[order])

    def camera_trajectory(self) -> Trajectory:
        """Every tracked frame's pose, re-expressed through its (possibly corrected) reference
        keyframe; lost frames have no pose and are left out."""
        corrected: dict[int, np.ndarray] = {}
        if self.snapshot is not None:
            corrected = {int(i): T for i, T in zip(self.snapshot.keyframe_indices, self.snapshot.keyframe_poses)}
        stamps, poses = [], []
        for idx in sorted(self.poses):
            p = self.poses[idx]
            if p.status == "lost":  # no pose was estimated: not written as a made-up one (issue 10)
                continue
            T_w_ref = corrected.get(int(p.ref_keyframe))
            poses.append(T_w_ref @ p.T_ref_cam if T_w_ref is not None else p.T_world_cam)
            stamps.append(p.timestamp)
        return Trajectory(stamps, np.array(poses).reshape(-1, 4, 4))

    # -- outputs -------------------------------------------------------------------------
    def write_frames_csv(self, path: Path) -> Path:
        """One row per frame: tracking outcome, enhancement decision and timings."""
        cols = ["index", "timestamp", "status", "keyframe", "inliers", "matches", "enhance_method",
                "mean_in", "mean_out", "enhance_ms", "orb_ms", "stereo_ms", "tracking_ms", "lines", "line_inliers",
                "loop_candidate"]
        rows = [",".join(cols)]
        loop_at = {int(lp.keyframe_index): int(lp.candidate) for lp in self.loops}  # keyframe closing a loop -> place
        for idx in sorted(self.poses):
            p = self.poses[idx]
            e, t = p.enhancement, p.timings_ms

            def num(v):
                return "" if v is None else f"{float(v):.3f}"

            rows.append(",".join([str(p.index), f"{p.timestamp:.9f}", p.status, str(int(p.is_keyframe)),
                                  str(p.n_inliers), str(p.n_matches), str(e.get("method", "")),
                                  num(e.get("mean_in")), num(e.get("mean_out")), num(t.get("enhance")),
                                  num(t.get("orb")), num(t.get("stereo")), num(t.get("total")),
                                  str(p.n_lines), str(p.n_line_inliers), str(loop_at.get(int(p.index), ""))]))
        path.write_text("\n".join(rows) + "\n")
        return path

    def tracking_summary(self) -> dict:
        statuses = [p.status for p in self.poses.values()]
        n = len(statuses)
        lost = statuses.count("lost")
        return {"frames_total": self.n_frames, "frames_processed": n, "frames_lost": lost,
                "keyframes": int(sum(p.is_keyframe for p in self.poses.values())),
                "tracking_success_percent": 100.0 * (n - lost) / n if n else 0.0,
                "coverage_percent": 100.0 * n / self.n_frames if self.n_frames else 0.0}

    def stats_summary(self) -> dict:
        names = sorted(self.actors, key=lambda a: ACTOR_ORDER.index(a) if a in ACTOR_ORDER else 99)
        return {name: self.actors[name].summary() for name in names}

    def write_outputs(self, out_dir: Path, gt: Trajectory | None, run_info: dict) -> dict:
        out_dir.mkdir(parents=True, exist_ok=True)
        cam = self.camera_trajectory()
        kfs = self.keyframe_trajectory()
        files = {}
        if len(cam):
            files["trajectory"] = str(write_tum(out_dir / "trajectory.tum", cam))
        if len(kfs):
            files["keyframes"] = str(write_tum(out_dir / "keyframes.tum", kfs))
        points = self.snapshot.points if self.snapshot is not None else np.zeros((0, 3), np.float32)
        files["map_points"] = str(write_ply_points(out_dir / "map_points.ply", np.asarray(points, np.float64)))
        lines = self.snapshot.lines if self.snapshot is not None else np.zeros((0, 2, 3), np.float32)
        if len(lines):
            files["map_lines"] = str(write_ply_lines(out_dir / "map_lines.ply", np.asarray(lines, np.float64)))
        files["frames"] = str(self.write_frames_csv(out_dir / "frames.csv"))
        metrics = evaluate_trajectory(cam, gt) if len(cam) else {"note": "no frame was tracked"}
        metrics["tracking"] = self.tracking_summary()
        metrics["map_points"] = int(len(points))
        metrics["map_lines"] = int(len(lines))
        metrics["loops"] = {"closed": len(self.loops),
                            "pairs": [{"keyframe": int(lp.keyframe_index), "candidate": int(lp.candidate),
                                       "inliers": int(lp.n_inliers)} for lp in self.loops]}
        metrics["run"] = run_info
        files["metrics"] = str(write_json(out_dir / "metrics.json", metrics))
        stats = self.stats_summary()
        files["stats"] = str(write_json(out_dir / "stats.json", stats))
        if len(cam) >= 2:
            try:
                title = f"{run_info.get('source', '')} ({run_info.get('clock', '')})"
                files["plot"] = str(plot_trajectory_png(out_dir / "trajectory.png", cam, gt, title=title))
            except Exception as exc:  # a plot must never cost the user the numbers
                files["plot_error"] = f"{type(exc).__name__}: {exc}"
        return {"metrics": metrics, "stats": stats, "files": files}


def format_summary(summary: dict, outcome_reason: str, n_cores: int) -> str:
    m = summary["metrics"]
    t = m["tracking"]
    lines = ["", "Canopy SLAM — run summary", "=" * 72,
             f"  outcome              {outcome_reason}",
             f"  frames               {t['frames_processed']}/{t['frames_total']} processed, "
             f"{t['keyframes']} keyframes, {t['frames_lost']} lost",
             f"  tracking success     {t['tracking_success_percent']:.1f} %",
             f"  map                  {m.get('map_points', 0)} points, {m.get('map_lines', 0)} line segments"]
    loops = m.get("loops") or {}
    if "loop_closing" in summary.get("stats", {}) or loops.get("closed"):
        lines.append(f"  loops closed         {loops.get('closed', 0)}")
    ate = m.get("ate")
    if ate and ate.get("rmse") is not None:
        lines.append(f"  ATE (SE3-aligned)    rmse {ate['rmse']:.4f} m   max {ate['max']:.4f} m   (n={ate['n']})")
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
