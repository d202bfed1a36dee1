#!/usr/bin/env python
"""Lockstep throughput and tracking service time through the actors, variants launched alternately
(s16-fps; s17-fps: + the tracking actor's service time p50 / mean, what bench_peers reports as
``track_ms_p50``).

Each variant is ``CHECKOUT[:CONFIG_OVERRIDES]``: ``launch.py`` of that checkout (its own
PYTHONPATH) on the dataset, lockstep, heartbeat 120 s (a loaded machine must not end a run), with
optional ``runtime.key=value`` lines merged into the dataset's config. Variants run A, B, A, B, ...
so the machine's load hits them alike. Per run: streaming frames/s (first to last tracked frame,
as bench_peers), CPU ms per frame of every actor thread (stats.json ``threads``), tracking's
waits (map update, stereo), the load average, and the trajectory's hash (bit identity).

    python docs/results/s16_fps/ab_launch.py --variant /tmp/fps/base --variant $PWD --reps 4 --out X.json
    python docs/results/s16_fps/ab_launch.py --variant $PWD:runtime.lockstep_extract_ahead=false --variant $PWD
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml


def variant_config(checkout: Path, dataset: str, overrides: list[str], folder: Path, tag: str) -> Path:
    raw = yaml.safe_load((checkout / "configs" / f"{dataset}.yaml").read_text()) or {}
    raw.setdefault("runtime", {})["heartbeat_timeout_s"] = 120.0
    for item in overrides:
        key, _, value = item.partition("=")
        section, _, field = key.partition(".")
        raw.setdefault(section, {})[field] = yaml.safe_load(value)
    path = folder / f"{tag}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def run_once(checkout: Path, config: Path, dataset: str, out: Path, max_frames: int | None,
             path: str | None = None) -> dict:
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    cmd = [sys.executable, "launch.py", "--dataset", dataset, "--config", str(config), "--out", str(out), "--quiet"]
    if max_frames:
        cmd += ["--max-frames", str(max_frames)]
    if path:
        cmd += ["--path", path]
    load0 = os.getloadavg()[0]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, cwd=checkout, env=env, capture_output=True, text=True)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{checkout}: launch failed\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    stats = json.loads((out / "stats.json").read_text())
    metrics = json.loads((out / "metrics.json").read_text())
    frames = metrics["tracking"]["frames_total"]
    ex = stats["tracking"]["extra"]
    t_first, t_last = ex["first_frame_done_at"], ex["last_frame_done_at"]
    cpu = {}
    for actor, st in stats.items():
        for thread, row in (((st or {}).get("extra") or {}).get("threads") or {}).items():
            cpu[f"{actor}/{thread}"] = row["cpu_ms_per_frame"]
    track = ex["threads"]["tracking"]
    return {"fps_streaming": (frames - 1) / (t_last - t_first), "fps": metrics["run"]["frames_per_s"],
            "launch_s": wall, "load": (load0 + os.getloadavg()[0]) / 2,
            "ate_m": (metrics.get("ate") or {}).get("rmse"), "keyframes": metrics["tracking"]["keyframes"],
            "trajectory_sha1": hashlib.sha1((out / "trajectory.tum").read_bytes()).hexdigest()[:12],
            "cpu_ms_per_frame": cpu, "cpu_total_ms_per_frame": round(sum(cpu.values()), 2),
            "track_runqueue_ms": track["runqueue_wait_ms_per_frame"],
            "track_blocked_ms": track.get("blocked_ms_per_frame"),
            "wait_ms": ex.get("wait_ms"), "stage_ms_p50": ex.get("stage_ms_p50"),
            "service_ms_p50": stats["tracking"]["service_ms"]["p50"], "service_ms_mean": stats["tracking"]["service_ms"]["mean"],
            "track_cpu_ms": track["cpu_ms_per_frame"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", action="append", required=True, help="CHECKOUT[:section.key=value[,...]]")
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--path", default=None, help="dataset folder (default: the bundled snippet)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="ab_launch_"))
    variants = []
    for i, v in enumerate(args.variant):
        checkout, _, over = v.partition(":")
        overrides = [o for o in over.split(",") if o]
        variants.append({"name": v, "checkout": Path(checkout).resolve(),
                         "config": variant_config(Path(checkout).resolve(), args.dataset, overrides, tmp, f"v{i}"),
                         "runs": []})
    for rep in range(args.reps):
        for i, v in enumerate(variants):
            r = run_once(v["checkout"], v["config"], args.dataset, tmp / f"run_v{i}_r{rep}", args.max_frames, args.path)
            v["runs"].append(r)
            print(f"rep {rep} v{i} {r['fps_streaming']:6.2f} fps  service p50 {r['service_ms_p50']:6.1f} ms  "
                  f"track cpu {r['track_cpu_ms']:5.1f} rq {r['track_runqueue_ms']:5.1f}  cpu {r['cpu_total_ms_per_frame']:6.1f} ms/frame  "
                  f"map wait {((r['wait_ms'] or {}).get('map_update') or {}).get('mean', float('nan')):6.2f}  "
                  f"load {r['load']:5.1f}  traj {r['trajectory_sha1']}  ATE {r['ate_m']:.4f}", flush=True)
    summary = []
    for i, v in enumerate(variants):
        runs = v["runs"]
        fps = np.array([r["fps_streaming"] for r in runs])
        keys = sorted({k for r in runs for k in r["cpu_ms_per_frame"]})
        row = {"variant": v["name"], "fps_streaming": fps.round(2).tolist(),
               "fps_streaming_median": float(np.median(fps)),
               "cpu_total_ms_per_frame_median": float(np.median([r["cpu_total_ms_per_frame"] for r in runs])),
               "cpu_ms_per_frame_median": {k: float(np.median([r["cpu_ms_per_frame"].get(k, 0.0) for r in runs]))
                                           for k in keys},
               "map_wait_mean_ms_median": float(np.median([((r["wait_ms"] or {}).get("map_update") or {}).get("mean", 0.0)
                                                           for r in runs])),
               "stereo_wait_mean_ms_median": float(np.median([((r["wait_ms"] or {}).get("stereo") or {}).get("mean", 0.0)
                                                              for r in runs])),
               "track_blocked_ms_median": float(np.median([r["track_blocked_ms"] or 0.0 for r in runs])),
               "track_runqueue_ms_median": float(np.median([r["track_runqueue_ms"] for r in runs])),
               "trajectories": sorted({r["trajectory_sha1"] for r in runs}),
               "load": [round(r["load"], 1) for r in runs],
               "service_ms_p50": [round(r["service_ms_p50"], 1) for r in runs],
               "service_ms_p50_median": float(np.median([r["service_ms_p50"] for r in runs]))}
        summary.append(row)
        print(f"v{i} {v['name']}\n   service p50 {row['service_ms_p50']} (median {row['service_ms_p50_median']:.1f}), "
              f"fps {row['fps_streaming']} (median {row['fps_streaming_median']:.2f}), "
              f"cpu {row['cpu_total_ms_per_frame_median']:.1f} ms/frame, map wait {row['map_wait_mean_ms_median']:.1f}, "
              f"stereo wait {row['stereo_wait_mean_ms_median']:.1f}, blocked {row['track_blocked_ms_median']:.1f}, "
              f"runqueue {row['track_runqueue_ms_median']:.1f}, trajectories {row['trajectories']}")
    if args.out:
        Path(args.out).write_text(json.dumps({"command": " ".join(sys.argv), "date": time.strftime("%Y-%m-%d %H:%M"),
                                              "summary": summary,
                                              "runs": {v["name"]: v["runs"] for v in variants}}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
