"""s32: cell_run.py with row_align.py imported (ROW_A / ROW_B / ROW_C in the environment)."""
import os
import runpy
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import row_align  # noqa: E402,F401

runpy.run_path(os.path.join(HERE, "cell_run.py"), run_name="__main__")
