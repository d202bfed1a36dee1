#!/usr/bin/env python
"""Per-stage cost of tracking and local mapping, in-process lockstep, with A/B variants
interleaved (issue 8: speed).

Every variant (``--variant "name:section.key=value,section.key=value"``; the dataset's shipped
config is always the first, "base") runs the same frames; variants alternate A B A B for
``--reps`` rounds so that a shared machine's load hits them alike. Per frame it records the
tracker's stage timings (wall ms), the CPU time of ``Tracker.track`` and of
``LocalMapper.insert_keyframe`` (``time.process_time``: all threads of this process), and the
lockstep time per frame (tracking + mapping of its keyframe), and each stage's CPU time on the
tracking thread (``<stage>_cpu`` of the timings, ``time.thread_time``): the critical path, which a
loaded machine's waiting does not inflate; the table shows these. Frames are read once, up front, so
disk reads are not counted. Prints one table and writes JSON.

    PYTHONPATH=$PWD python benchmarks/profile_tracking.py --dataset kitti
    PYTHONPATH=$PWD python benchmarks/profile_tracking.py --dataset euroc --reps 3 \\
        --variant "gtsam:mapping.ba_solver=gtsam" --variant "nolag:runtime.map_update_lag_frames=0"

Map updates are applied as in the actors' lockstep (``canopy.pipeline.MapUpdateSchedule``,
``runtime.map_update_lag_frames``); the in-process wall time adds mapping to tracking whatever the
lag, so the lag's speed shows only through the actors (``launch.py``, ``bench_peers.py``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CV_THREADS = cv2.getNumThreads()
sys.path.insert(0, str(ROOT))

from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_variant, with_settings  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402

STAGES = ("noise_estimate", "orb", "stereo", "match_motion", "pnp", "track_local_map", "keyframe", "total",
          "stereo_worker", "orb_right", "stereo_pyramids")
# the last three: the worker thread (parallel_stereo): its stereo matching after the left keypoints are in,
# the right ORB, and the SAD pyramids it builds before that wait (absent on frames it does not prebuild)
MAP_STAGES = ("insert", "window", "ba", "cull", "update", "total")


def run_once(dataset: str, frames, calib, sets) -> dict:
    cfg = with_settings(load_run_config(dataset), sets)
    tp, mp, rt = cfg.tracking, cfg.mapping, cfg.runtime
    # as the tracking actor sets its process (here local mapping shares the setting)
    cv2.setNumThreads(tp.opencv_threads if tp.opencv_threads > 0 else DEFAULT_CV_THREADS)
    tracker, mapper = Tracker(calib, tp), LocalMapper(calib, mp)
    schedule = MapUpdateSchedule(effective_map_update_lag(rt.map_update_lag_frames, tp))
    track_cpu, map_cpu, step_wall, stage, map_stage = [], [], [], [], []
    poses, refs, rel, reasons = [], [], [], {}
    for frame in frames:
        w0, c0 = time.perf_counter(), time.process_time()
        for update in schedule.take_due(frame.index):
            tracker.apply_map_update(update)
        res = tracker.track(frame)
        track_cpu.append((time.process_time() - c0) * 1e3)
        stage.append(res.timings)
        if res.is_keyframe and res.keyframe is not None:
            for why in (res.keyframe_reason or "init").split("+"):
                reasons[why] = reasons.get(why, 0) + 1
            c1 = time.process_time()
            update = mapper.insert_keyframe(res.keyframe)
            map_cpu.append((time.process_time() - c1) * 1e3)
            map_stage.append(update.timings)
            schedule.keyframe_sent(res.keyframe.index, frame.index)
            schedule.hold(update)
        step_wall.append((time.perf_counter() - w0) * 1e3)
        poses.append(res.T_world_cam.copy())
        refs.append(res.reference_kf_index)
        rel.append(res.T_ref_cam)
    kf = mapper.keyframe_poses()
    est = np.array([kf[r] @ T if T is not None and r in kf else P for P, r, T in zip(poses, refs, rel)])
    return {"track_cpu": track_cpu, "map_cpu": map_cpu, "step_wall": step_wall, "stage": stage,
            "map_stage": map_stage, "est": est, "keyframes": len(map_cpu),
            "keyframe_reasons": reasons}


def p50(values) -> float | None:
    return float(np.percentile(values, 50)) if len(values) else None


def _sum_or_none(d: dict, keys, optional=()) -> float | None:
    """Sum of ``d``'s values at ``keys`` (None if one is missing) plus those of ``optional`` present."""
    if any(d.get(k) is None for k in keys):
        return None
    return float(sum(d[k] for k in keys) + sum(d[k] for k in optional if d.get(k) is not None))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--path", default=None)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--variant", action="append", default=[], help='"name:section.key=value,..."')
    ap.add_argument("--out", type=Path, default=None, help="JSON (default docs/results/profile_tracking_<dataset>.json)")
    a = ap.parse_args()
    src = open_source("euroc" if a.dataset == "synthetic" else a.dataset, a.path, max_frames=a.max_frames)
    frames = [src.frame(i) for i in range(len(src))]
    gt = src.ground_truth.poses[: len(frames)] if src.ground_truth is not None else None
    variants = [("base", [])] + [parse_variant(v) for v in a.variant]
    runs: dict[str, list[dict]] = {name: [] for name, _ in variants}
    for _ in range(a.reps):
        for name, sets in variants:  # A B A B: the machine's load falls on every variant alike
            runs[name].append(run_once(a.dataset, frames, src.calibration, sets))
    rows = []
    for name, sets in variants:
        rs = runs[name]
        cat = lambda key: np.concatenate([r[key] for r in rs]) if any(len(r[key]) for r in rs) else np.zeros(0)  # noqa: E731
        stage = {s: p50([t[s] for r in rs for t in r["stage"] if s in t]) for s in STAGES}
        stage_cpu = {s: p50([t[s + "_cpu"] for r in rs for t in r["stage"] if s + "_cpu" in t]) for s in STAGES}
        map_stage = {s: p50([t[s] for r in rs for t in r["map_stage"] if s in t]) for s in MAP_STAGES}
        ate = float(ape(rs[0]["est"], gt, align="se3")["rmse"]) if gt is not None else None
        n = len(frames)
        rows.append({"variant": name, "sets": [f"{s}.{f}={v}" for s, f, v in sets], "frames": n,
                     "keyframes": rs[0]["keyframes"], "keyframe_reasons": rs[0]["keyframe_reasons"], "ate_m": ate,
                     "track_cpu_ms_p50": p50(cat("track_cpu")),
                     "track_thread_cpu_ms_p50": stage_cpu["total"], "map_cpu_ms_p50": p50(cat("map_cpu")),
                     "lockstep_cpu_ms_per_frame": float(np.mean([(np.sum(r["track_cpu"]) + np.sum(r["map_cpu"])) / n
                                                                 for r in rs])),
                     "map_cpu_ms_per_frame": float(np.mean([np.sum(r["map_cpu"]) / n for r in rs])),
                     "lockstep_wall_ms_per_frame": float(np.mean([np.mean(r["step_wall"]) for r in rs])),
                     "stage_wall_ms_p50": stage, "stage_cpu_ms_p50": stage_cpu, "mapping_stage_wall_ms_p50": map_stage})
    fmt = lambda v, s=".1f": "-" if v is None else format(v, s)  # noqa: E731
    print(f"{a.dataset}: {len(frames)} frames, {a.reps} interleaved reps (track cpu = process time, all threads; "
          "thread = tracking thread CPU; stages: tracking-thread CPU ms p50)")
    print(f"{'variant':12s} {'kf':>4s} {'ATE m':>7s} {'track cpu p50':>13s} {'map cpu p50':>11s} "
          f"{'thread p50':>10s} {'cpu/frame':>9s} {'wall/frame':>10s}   " + " ".join(f"{s[:8]:>8s}" for s in STAGES))
    for r in rows:
        print(f"{r['variant']:12s} {r['keyframes']:4d} {fmt(r['ate_m'], '.4f'):>7s} {fmt(r['track_cpu_ms_p50']):>13s} "
              f"{fmt(r['map_cpu_ms_p50']):>11s} {fmt(r['track_thread_cpu_ms_p50']):>10s} {fmt(r['lockstep_cpu_ms_per_frame']):>9s} "
              f"{fmt(r['lockstep_wall_ms_per_frame']):>10s}   "
              + " ".join(f"{fmt(r['stage_cpu_ms_p50'][s]):>8s}" for s in STAGES))
        print(f"{'':12s} keyframe reasons {r['keyframe_reasons']}; worker thread CPU p50 "
              f"{fmt(_sum_or_none(r['stage_cpu_ms_p50'], ('orb_right', 'stereo_worker'), ('stereo_pyramids',)))} ms; "
              f"mapping CPU per frame {fmt(r['map_cpu_ms_per_frame'])} ms")
        print(f"{'':12s} mapping wall p50: " + ", ".join(f"{k} {fmt(v)}" for k, v in r["mapping_stage_wall_ms_p50"].items()))
    out = a.out or ROOT / "docs" / "results" / f"profile_tracking_{a.dataset}.json"
    write_json(out, {"dataset": a.dataset, "path": a.path, "frames": len(frames), "reps": a.reps,
                     "date": time.strftime("%Y-%m-%d %H:%M"), "command": " ".join(sys.argv),
                     "note": "shared 2-core machine: wall times are noisy, CPU times less so", "rows": rows})
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
