"""s32: one in-process grid run (bench_enhance_diagnose.run, KITTI config, method auto) of a cell folder or
"clean", with section.field=value settings; prints ATE, Sim(3) ATE, scale as JSON.

    PYTHONPATH=$PWD python docs/results/s32_oracle/cell_run.py CELL [tracking.x=v ...]
"""
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from oracle_common import run_cell  # noqa: E402

cell = sys.argv[1]
res, rows = run_cell(None if cell == "clean" else cell, sys.argv[2:])
print(json.dumps({"cell": Path(cell).name, "set": sys.argv[2:], "ate_mm": res.get("ate", float("nan")) * 1e3,
                  "sim3": res.get("ate_sim3", float("nan")) * 1e3, "scale": res.get("scale"),
                  "tracked": res["tracked"]}))
