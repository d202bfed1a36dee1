"""A long hover's ATE by pass (docs/notes/s16-culling.md): s15's ping-pong hover (docs/results/s15_stillcost/hover.py,
the still EuRoC snippet played forth and back REPS times) in process as the grid runs it, with the error of each
95-frame pass after one SE(3) alignment of the whole run, and the keyframes the map holds at the end.

Throw-away measurement script, run from the tree to measure (its configs/euroc.yaml), e.g.
    REPS=5 CELL=g1-b0.06-low CELLS_DIR=/work/cache/degraded python docs/results/s16_culling/hover_ate.py [mapping.x=v ...]
"""
import os, sys, warnings
warnings.simplefilter("ignore")
sys.path.insert(0, os.getcwd())
import numpy as np
import benchmarks.bench_enhance_diagnose as bed
from canopy.config import parse_value
from canopy.metrics import align_trajectory
from canopy.sources import BUNDLED_DATA

os.environ.setdefault("REPS", "5")
hover = {}
exec(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "../s15_stillcost/hover.py")).read()
     .split("bed.open_source = ")[0], hover)   # PingPong and REPS, without running mapcost
_open = bed.open_source
bed.open_source = lambda *a, **k: hover["PingPong"](_open(*a, **k))
seen = {}
_ape = bed.ape
bed.ape = lambda est, gt, align="se3": seen.update(est=est, gt=gt) or _ape(est, gt, align)
mappers = []
_LM = bed.LocalMapper
bed.LocalMapper = lambda *a, **k: mappers.append(_LM(*a, **k)) or mappers[-1]
cell = os.environ.get("CELL", "g1-b0.06-low")
cells = os.environ.get("CELLS_DIR", "/work/cache/degraded").rstrip("/")
path = BUNDLED_DATA["euroc"] if cell == "clean" else f"{cells}/euroc-all-{cell}-seed{os.environ.get('SEED', '0')}"
tr, mp = {}, {}
for s in sys.argv[1:]:
    key, v = s.split("=", 1)
    sec, name = key.split(".")
    (mp if sec == "mapping" else tr)[name] = parse_value(v)
out, rows = bed.run(path, BUNDLED_DATA["euroc"], "euroc", {"method": "auto"}, tr, None, stereo=False, kind="euroc",
                    map_sets=mp)
est = align_trajectory(seen["est"], seen["gt"])
err = np.linalg.norm(est[:, :3, 3] - seen["gt"][:, :3, 3], axis=1) * 1e3
m = mappers[-1]
print(f"CELL {cell} REPS {hover['REPS']} {sys.argv[1:]}: ATE {out['ate'] * 1e3:.4f} mm over {len(err)} frames, "
      f"tracked {out['tracked']:.3f}, keyframes held {len(m.keyframes)}, culled {m.n_keyframes_culled}")
n = len(err) // hover["REPS"]
print("  per pass (rmse mm): " + " ".join(f"{np.sqrt(np.mean(err[i * n:(i + 1) * n] ** 2)):.3f}"
                                          for i in range(hover["REPS"])))
# each pass aligned on its own (its jitter) and where it sits against the ground truth after the global alignment
# (an offset between passes is drift of the map over the hover)
own = []
for i in range(hover["REPS"]):
    sl = slice(i * n, (i + 1) * n)
    a = align_trajectory(seen["est"][sl], seen["gt"][sl])
    own.append(np.sqrt(np.mean(np.sum((a[:, :3, 3] - seen["gt"][sl, :3, 3]) ** 2, axis=1))) * 1e3)
print("  per pass, aligned alone (rmse mm): " + " ".join(f"{e:.3f}" for e in own))
off = [(est[i * n:(i + 1) * n, :3, 3] - seen["gt"][i * n:(i + 1) * n, :3, 3]).mean(axis=0) * 1e3 for i in range(hover["REPS"])]
print("  per pass, mean offset after the global alignment (mm): " + " ".join(f"[{o[0]:.2f} {o[1]:.2f} {o[2]:.2f}]" for o in off))
