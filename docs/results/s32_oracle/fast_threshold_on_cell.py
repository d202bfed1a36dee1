"""s32: a degraded cell with the AFE Eq. 18 threshold on enhanced frames replaced by a fixed one (the rest of the
rule kept: Eq. 19 fallback, corner budget, extractor choice). "auto": unchanged.

    PYTHONPATH=$PWD python docs/results/s32_oracle/fast_threshold_on_cell.py CELL 28
"""
import sys, json
from pathlib import Path
import benchmarks.bench_enhance_diagnose as bd
from canopy.sources import BUNDLED_DATA
cell, theta = sys.argv[1], sys.argv[2]
orig = bd.tracking_fast_arguments
def patched(image, decision, params, n):
    a = orig(image, decision, params, n)
    if a and theta != 'auto':
        a['fast_threshold'] = int(theta)
    return a
bd.tracking_fast_arguments = patched
res, rows = bd.run(Path(cell), BUNDLED_DATA["kitti"], "kitti", {"method": "auto"}, {}, None, stereo=False, kind="kitti")
print(json.dumps({"cell": Path(cell).name, "theta": theta, "ate_mm": res["ate"]*1e3, "sim3": res["ate_sim3"]*1e3, "scale": res["scale"], "tracked": res["tracked"], "thr": [r["thr"] for r in rows][:3]}))
