#!/usr/bin/env python
"""The tracking thread's wall time per KITTI frame beyond its CPU and its run-queue wait (time it
slept: the worker's stereo, the GIL) under different ``sys.setswitchinterval`` values, toggled
frame by frame in one process (s16-fps). Tracker only (no mapping), the default config.

    python docs/results/s16_fps/switch_interval.py --reps 3 --intervals 0.005 0.001 0.0005
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from actors.schedstat import thread_schedstat
    from canopy.config import load_run_config
    from canopy.frontend import Tracker
    from canopy.sources import open_source

    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--intervals", type=float, nargs="+", default=[0.005, 0.001, 0.0005])
    args = ap.parse_args(argv)
    cfg = load_run_config(args.dataset)
    src = open_source(args.dataset, None)
    frames = [src.frame(i) for i in range(len(src))]
    me = threading.get_native_id()
    rows = {iv: {"wall": [], "cpu": [], "rq": [], "stereo": [], "worker_cpu": []} for iv in args.intervals}
    poses = {iv: [] for iv in args.intervals}
    for rep in range(args.reps):
        trackers = {iv: Tracker(src.calibration, cfg.tracking) for iv in args.intervals}
        for f in frames:
            order = args.intervals if (f.index + rep) % 2 == 0 else args.intervals[::-1]
            for iv in order:
                sys.setswitchinterval(iv)
                s0 = thread_schedstat()[me]
                t0, c0 = time.perf_counter(), time.thread_time()
                res = trackers[iv].track(f)
                wall, cpu = (time.perf_counter() - t0) * 1e3, (time.thread_time() - c0) * 1e3
                s1 = thread_schedstat()[me]
                r = rows[iv]
                r["wall"].append(wall)
                r["cpu"].append(cpu)
                r["rq"].append((s1[1] - s0[1]) * 1e-6)
                r["stereo"].append(res.timings.get("stereo", 0.0))
                r["worker_cpu"].append(res.timings.get("orb_right_cpu", 0) + res.timings.get("stereo_pyramids_cpu", 0)
                                       + res.timings.get("stereo_worker_cpu", 0))
                if rep == 0:
                    poses[iv].append(res.T_world_cam.copy())
    sys.setswitchinterval(0.005)
    ref = np.asarray(poses[args.intervals[0]])
    for iv, r in rows.items():
        a = {k: np.asarray(v) for k, v in r.items()}
        slept = a["wall"] - a["cpu"] - a["rq"]
        same = np.array_equal(np.asarray(poses[iv]), ref)
        print(f"switch {iv * 1e3:5.2f} ms: wall {a['wall'].mean():6.2f}  cpu {a['cpu'].mean():6.2f}  rq {a['rq'].mean():6.2f}  "
              f"slept {slept.mean():6.2f} (p50 {np.median(slept):5.2f})  stereo wait {a['stereo'].mean():5.2f}  "
              f"worker cpu {a['worker_cpu'].mean():6.2f}  poses identical to the first: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
