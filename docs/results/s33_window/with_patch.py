"""s33: run a script with one of this folder's patches imported first: with_patch.py PATCH SCRIPT [args...]"""
import importlib
import os
import runpy
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "s32_oracle"))
patch = importlib.import_module(sys.argv.pop(1))
script = sys.argv.pop(1)
sys.argv[0] = script
runpy.run_path(script, run_name="__main__")
if hasattr(patch, "STATS"):
    print(patch.STATS, file=sys.stderr)
