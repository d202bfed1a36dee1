"""s32: cell_run.py with one of this folder's experiment patches imported first (its settings in the environment:
offset_field KV / KU / D0 / KAPPA, right_budget RIGHT_FACTOR, row_align ROW_A / ROW_B / ROW_C, vertical_blur
VB / HB, near_fill NEAR_MIN_DISP).

    PYTHONPATH=$PWD KV=-0.2 python docs/results/s32_oracle/cell_run_with.py offset_field CELL [tracking.x=v ...]
    RUNNER="docs/results/s32_oracle/cell_run_with.py near_fill" bash docs/results/s32_oracle/sweep.sh ...
"""
import importlib
import os
import runpy
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
PATCHES = ("offset_field", "right_budget", "row_align", "vertical_blur", "near_fill")
if len(sys.argv) < 3 or sys.argv[1] not in PATCHES:
    sys.exit(f"usage: cell_run_with.py {{{'|'.join(PATCHES)}}} CELL [section.field=value ...]")
patch = importlib.import_module(sys.argv.pop(1))
runpy.run_path(os.path.join(HERE, "cell_run.py"), run_name="__main__")
if hasattr(patch, "STATS"):
    print(patch.STATS, file=sys.stderr)
