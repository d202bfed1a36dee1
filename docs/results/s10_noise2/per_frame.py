# One in-process run of a degraded preset cell (the grid's runner, benchmarks/bench_enhance_diagnose.run,
# method auto), saving the estimated and true poses and the per-frame rows to an npz, for comparing
# the smoothed sub-pixel refinement on / off frame by frame.
# Usage: per_frame.py CELL|PRESET-clean[-N] OUT.npz [tracking.field=value ...]
import sys
import numpy as np
import benchmarks.bench_enhance_diagnose as bd
from canopy.config import parse_value
cell, out_path, sets = sys.argv[1], sys.argv[2], sys.argv[3:]
track = {k.split(".", 1)[1]: parse_value(v) for k, v in (s.split("=", 1) for s in sets)}
captured = {}
orig_ape = bd.ape
def ape(est, gt, align="se3"):
    captured.setdefault("est", est); captured.setdefault("gt", gt)
    return orig_ape(est, gt, align)
bd.ape = ape
preset = cell.split("-")[0] + "-" + cell.split("-")[1]
if "-clean" in cell:  # haze-row-clean: the clean preset, full length; day-loop-clean-300: its first 300 frames
    path, n = f"/work/cache/synthetic/{preset}-seed0-full", (int(cell.split("-")[3]) if cell.count("-") == 3 else None)
else:
    path, n = f"/work/cache/degraded/{cell}", int(cell.split("-")[2])
out, rows = bd.run(path, f"/work/cache/synthetic/{preset}-seed0-full", "synthetic",
                   {"method": "auto"}, track, n, stereo=False, kind="euroc")
keys = ["inl", "matches", "noise", "sigma"]
np.savez(out_path, est=captured["est"], gt=captured["gt"],
         status=np.array([r["status"] for r in rows]),
         **{k: np.array([np.nan if r.get(k) is None else float(r[k]) for r in rows]) for k in keys})
print(out)
