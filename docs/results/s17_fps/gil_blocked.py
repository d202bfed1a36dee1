"""How long the tracking thread sleeps (neither on a CPU nor on a run queue) while it extracts the
left image's ORB and its worker extracts the right one, in process, KITTI (s17-fps).

Per frame, around ``Tracker.extract`` (noise, left ORB on this thread; the worker's right ORB runs
meanwhile): wall time, this thread's CPU and run-queue wait (``/proc/self/task/<tid>/schedstat``);
the rest, "asleep", is waiting for the GIL (the worker holds it in its Python between OpenCV calls)
or for OpenCV's pool. The same for the worker's job. Compare with the worker turned off
(``parallel_stereo: false``, ``parallel_extraction: false``: both images on this thread, nothing to
wait for), alternately, --reps rounds.

    PYTHONPATH=$PWD python docs/results/s17_fps/gil_blocked.py --reps 2
"""
import argparse
import dataclasses
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def schedstat(tid: int) -> tuple[float, float]:
    run_ns, wait_ns = open(f"/proc/self/task/{tid}/schedstat").read().split()[:2]
    return int(run_ns) * 1e-6, int(wait_ns) * 1e-6


ap = argparse.ArgumentParser()
ap.add_argument("--dataset", default="kitti")
ap.add_argument("--reps", type=int, default=2)
a = ap.parse_args()
cfg = load_run_config(a.dataset)
src = open_source(a.dataset, None)
frames = [src.frame(i) for i in range(len(src))]
me = threading.get_native_id()
variants = {"worker": cfg.tracking,
            "serial": dataclasses.replace(cfg.tracking, parallel_stereo=False, parallel_extraction=False)}
out = {k: {"wall": [], "cpu": [], "rq": [], "asleep": []} for k in variants}
for rep in range(a.reps):
    for name, tp in variants.items():
        tracker, mapper = Tracker(src.calibration, tp), LocalMapper(src.calibration, cfg.mapping)
        schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp))
        for frame in frames:
            for update in schedule.take_due(frame.index):
                tracker.apply_map_update(update)
            c0, q0 = schedstat(me)
            t0 = time.perf_counter()
            ex = tracker.extract(frame)
            wall = (time.perf_counter() - t0) * 1e3
            c1, q1 = schedstat(me)
            res = tracker.track_extracted(ex)
            if frame.index > 0:
                row = out[name]
                row["wall"].append(wall)
                row["cpu"].append(c1 - c0)
                row["rq"].append(q1 - q0)
                row["asleep"].append(wall - (c1 - c0) - (q1 - q0))
            if res.is_keyframe:
                update = mapper.insert_keyframe(res.keyframe)
                schedule.keyframe_sent(res.keyframe.index, frame.index)
                schedule.hold(update)
print(f"{a.dataset}, {a.reps} reps, load {os.getloadavg()[0]:.1f}: Tracker.extract on the tracking thread, ms per frame p50 (mean)")
for name, row in out.items():
    print(f"  {name:7s} " + "  ".join(f"{k} {np.median(v):6.2f} ({np.mean(v):6.2f})" for k, v in row.items()))
