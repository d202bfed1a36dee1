"""Local mapping per keyframe on a recording of benchmarks/ab_mapping.py: the mapper's own stage
timings (insert_keyframe's `timings`, thread CPU added here) and a cProfile of the replay.

    PYTHONPATH=$PWD python docs/results/s17_mapcost/prof_map.py /tmp/rec_kitti.pkl [--reps 3] [--cprofile N]
"""
import argparse, cProfile, pickle, pstats, sys, time
from collections import defaultdict

import numpy as np

from canopy.backend import LocalMapper
from canopy.config import load_run_config

ap = argparse.ArgumentParser()
ap.add_argument("recording")
ap.add_argument("--reps", type=int, default=3)
ap.add_argument("--cprofile", type=int, default=0, help="print the top N functions by cumulative time")
ap.add_argument("--set", action="append", default=[], help="mapping.key=value overrides")
a = ap.parse_args()
with open(a.recording, "rb") as f:
    rec = pickle.load(f)
params = load_run_config(rec["dataset"]).mapping
for s in a.set:
    k, v = s.split("=")
    k = k.split(".")[-1]
    old = getattr(params, k)
    setattr(params, k, type(old)(float(v)) if not isinstance(old, bool) else v.lower() in ("1", "true"))
kfs = [pickle.loads(b) for b in rec["keyframes"]]
stages = defaultdict(list)
prof = cProfile.Profile() if a.cprofile else None
cpu = []
for r in range(a.reps):
    mapper = LocalMapper(rec["calibration"], params)
    tot = 0.0
    for blob in rec["keyframes"]:
        kf = pickle.loads(blob)
        if prof and r == a.reps - 1:
            prof.enable()
        t0 = time.thread_time()
        u = mapper.insert_keyframe(kf)
        tot += time.thread_time() - t0
        if prof and r == a.reps - 1:
            prof.disable()
        for k, v in u.timings.items():
            stages[k].append(v)
    cpu.append(tot / len(kfs) * 1e3)
n = len(kfs)
print(f"{rec['dataset']}: {n} keyframes; thread CPU per keyframe (reps): {' '.join(f'{c:.2f}' for c in cpu)}")
for k, v in stages.items():
    print(f"  {k:12s} wall mean {np.sum(v) / (a.reps * n):7.2f} ms per keyframe")
if prof:
    pstats.Stats(prof).sort_stats("cumulative").print_stats(a.cprofile)
    pstats.Stats(prof).sort_stats("tottime").print_stats(a.cprofile)
