"""s32: cell_run.py with right_budget.py imported (RIGHT_FACTOR in the environment)."""
import os
import runpy
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import right_budget  # noqa: E402,F401

runpy.run_path(os.path.join(HERE, "cell_run.py"), run_name="__main__")
