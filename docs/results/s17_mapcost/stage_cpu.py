"""Local mapping's thread CPU per keyframe by step, replaying a recording of benchmarks/ab_mapping.py
(``--recording``) in this checkout: each step's method wrapped with ``time.thread_time`` (nested steps
are also inside their parents; "rest" = insert_keyframe minus the top-level steps).

    PYTHONPATH=$PWD python docs/results/s17_mapcost/stage_cpu.py /tmp/rec_kitti.pkl [--reps 3]
"""
import argparse, pickle, sys, time
from collections import defaultdict

import numpy as np

import canopy.backend.keyframe_culling as kc
import canopy.backend.local_ba as lba
import canopy.backend.local_mapper as lmm
import canopy.backend.map_store as ms
from canopy.backend import LocalMapper
from canopy.config import load_run_config

ap = argparse.ArgumentParser()
ap.add_argument("recording")
ap.add_argument("--reps", type=int, default=3)
a = ap.parse_args()
acc = defaultdict(float)


def wrap(owner, name, label):
    f = getattr(owner, name)

    def timed(*args, **kw):
        t0 = time.thread_time()
        try:
            return f(*args, **kw)
        finally:
            acc[label] += time.thread_time() - t0
    setattr(owner, name, timed)


TOP = [(LocalMapper, "_insert", "insert (all)"), (LocalMapper, "_local_window", "window"),
       (LocalMapper, "_bundle_adjust", "BA (all)"), (LocalMapper, "_cull", "landmark culling"),
       (lmm, "cull_redundant_keyframes", "keyframe culling"), (LocalMapper, "_make_update", "update for tracking"),
       (lmm, "bounded_fixed", "bounded fixed set")]
SUB = [(LocalMapper, "_update_descriptors", "  insert: distinctive descriptors"),
       (LocalMapper, "_add_seen_counts", "  insert: seen counts"),
       (LocalMapper, "_covisible", "  covisibility counts (window + keyframe culling)"),
       (lmm, "window_neighbours", "  window: still-window neighbours"),
       (LocalMapper, "_observation_edges", "  BA: observation edges"),
       (lba, "bundle_adjust_points", "  BA: LM (bundle_adjust_points)"),
       (LocalMapper, "_remove_observation", "  BA: outlier observations removed"),
       (kc, "redundant_fraction", "  keyframe culling: redundancy"),
       (kc, "cull_keyframe", "  keyframe culling: culling one")]
for o, n, l in TOP + SUB:
    wrap(o, n, l)
with open(a.recording, "rb") as f:
    rec = pickle.load(f)
params = load_run_config(rec["dataset"]).mapping
totals = []
for _ in range(a.reps):
    mapper = LocalMapper(rec["calibration"], params)
    t = 0.0
    for blob in rec["keyframes"]:
        kf = pickle.loads(blob)
        t0 = time.thread_time()
        mapper.insert_keyframe(kf)
        t += time.thread_time() - t0
    totals.append(t)
nk = len(rec["keyframes"])
n = nk * a.reps
tot = sum(totals) / n * 1e3
print(f"{rec['dataset']}: {nk} keyframes x {a.reps}; insert_keyframe {tot:.2f} ms thread CPU per keyframe "
      f"(reps {' '.join(f'{x / nk * 1e3:.1f}' for x in totals)})")
top = 0.0
for o, nme, l in TOP + SUB:
    v = acc[l] / n * 1e3
    if not l.startswith("  "):
        top += v
    print(f"  {l:50s} {v:6.2f}")
print(f"  {'rest':50s} {tot - top:6.2f}")
