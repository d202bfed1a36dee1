"""Local mapping's cost per keyframe on one EuRoC grid cell, in process as the grid runs it (docs/notes/s15-stillcost.md).

Throw-away measurement script, run from the worktree root:
    CELL=g1-b0.06-low [SEED=0] python docs/results/s15_stillcost/mapcost.py [tracking.x=v] [mapping.y=v] ...
CELL=clean runs the bundled snippet. Prints ATE (final poses, as the grid), tracked share, keyframes, and local
mapping's thread CPU per keyframe by thirds of the keyframes, per stage (thread CPU too), with the window's sizes, the map's size
and the observations per landmark. VERBOSE=1 adds a line per keyframe; FRAMES=1 a line per frame.
"""
import os, sys, time, warnings
warnings.simplefilter("ignore")
sys.path.insert(0, os.getcwd())
import numpy as np
import canopy.backend.local_mapper as lm
from benchmarks.bench_enhance_diagnose import run
from canopy.config import parse_value
from canopy.sources import BUNDLED_DATA

# the mapper's stage timings (perf_counter, wall) as this thread's CPU instead: loaded-machine robust
lm.time = type("T", (), {"perf_counter": staticmethod(time.thread_time)})
recs = []
_ins = lm.LocalMapper.insert_keyframe


def ins(self, kf):
    c0 = time.thread_time()
    up = _ins(self, kf)
    cpu = (time.thread_time() - c0) * 1e3
    n_obs = [len(l.obs) for l in self.landmarks.values()]
    recs.append(dict(self.timings[-1], cpu=cpu, kf=kf.index, n_local=len(self.last_window[0]),
                     n_fixed=len(self.last_window[1]), n_kf=len(self.keyframes), n_lm=len(self.landmarks),
                     obs_mean=float(np.mean(n_obs)) if n_obs else 0.0, n_upd=len(up.landmark_ids),
                     kf_culled=getattr(self, "n_keyframes_culled", 0)))
    return up


lm.LocalMapper.insert_keyframe = ins
cell = os.environ.get("CELL", "g1-b0.06-low")
seed = os.environ.get("SEED", "0")
path = BUNDLED_DATA["euroc"] if cell == "clean" else f"/work/cache/degraded/euroc-all-{cell}-seed{seed}"
enh, tr, mp = {"method": "auto"}, {}, {}
for s in sys.argv[1:]:
    key, v = s.split("=", 1)
    sec, name = key.split(".")
    (enh if sec == "enhancement" else mp if sec == "mapping" else tr)[name] = parse_value(v)
out, rows = run(path, BUNDLED_DATA["euroc"], "euroc", enh, tr, None, per_frame=False, stereo=False, kind="euroc", map_sets=mp)
n_frames = len(rows)
print(f"CELL {cell} seed {seed} {sys.argv[1:]}")
print(f"ATE {out.get('ate', float('nan')) * 1e3:.4f} mm, tracked {out['tracked']:.3f}, keyframes {len(recs)}, "
      f"culled {recs[-1]['kf_culled'] if recs else 0}")
cpu = np.array([r["cpu"] for r in recs])
print(f"local mapping CPU {cpu.mean():.1f} ms per keyframe, {cpu.sum() / n_frames:.2f} ms per frame ({n_frames} frames)")
thirds = np.array_split(np.arange(len(recs)), 6 if os.environ.get("SIXTHS") else 3)
keys = ["cpu", "insert", "window", "ba", "cull", "kfcull", "update", "n_local", "n_fixed", "n_kf", "n_lm", "obs_mean", "n_upd"]
for name, idx in zip([f"part {i + 1}/{len(thirds)}" for i in range(len(thirds))], thirds):
    print(f"  {name:8s}: " + ", ".join(f"{k} {np.mean([recs[i].get(k, 0) for i in idx]):.1f}" for k in keys))
if os.environ.get("VERBOSE"):
    for r in recs:
        print("  kf", ", ".join(f"{k} {r.get(k, 0):.1f}" for k in ["kf"] + keys))
if os.environ.get("FRAMES"):
    for r in rows:
        print("  frame", r["i"], r["status"], r["inl"], r["matches"], r.get("reason"))
