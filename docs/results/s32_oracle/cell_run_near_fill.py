"""s32: cell_run.py with near_fill.py imported (NEAR_MIN_DISP in the environment)."""
import os
import runpy
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import near_fill  # noqa: E402,F401

runpy.run_path(os.path.join(HERE, "cell_run.py"), run_name="__main__")
print(near_fill.STATS, file=sys.stderr)
