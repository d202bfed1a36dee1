"""s32: one in-process grid run (bench_enhance_diagnose.run, KITTI config, method auto) of a cell folder or
"clean", with section.field=value settings; prints ATE, Sim(3) ATE, scale as JSON.

    PYTHONPATH=$PWD python docs/results/s32_oracle/cell_run.py CELL [tracking.x=v ...]
"""
import sys, json
from pathlib import Path
from benchmarks.bench_enhance_diagnose import run
from canopy.sources import BUNDLED_DATA
from canopy.config import parse_value
cell = sys.argv[1]
ts = {}; ms = {}; es = {}
for s in sys.argv[2:]:
    k, v = s.split('=', 1); sec, f = k.split('.')
    {'tracking': ts, 'mapping': ms, 'enhancement': es}[sec][f] = parse_value(v)
path = BUNDLED_DATA['kitti'] if cell == 'clean' else Path(cell)
res, rows = run(path, BUNDLED_DATA["kitti"], "kitti", {"method": "auto", **es}, ts, None, stereo=False, kind="kitti", map_sets=ms)
print(json.dumps({"cell": Path(cell).name, "set": sys.argv[2:], "ate_mm": res.get("ate", float('nan'))*1e3, "sim3": res.get("ate_sim3", float('nan'))*1e3, "scale": res.get("scale"), "tracked": res["tracked"]}))
