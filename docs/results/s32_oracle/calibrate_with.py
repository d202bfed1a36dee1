#!/usr/bin/env python
"""s32: benchmarks/calibrate_disparity_offset.py with tracking settings over the config's.

    PYTHONPATH=$PWD python docs/results/s32_oracle/calibrate_with.py tracking.subpixel_window=7 -- --dataset kitti --method map
"""
import runpy
import sys
from dataclasses import replace

import canopy.config as config

i = sys.argv.index("--")
sets = dict(a.split("=", 1) for a in sys.argv[1:i])
orig = config.load_run_config


def load(*a, **k):
    cfg = orig(*a, **k)
    ts = {key.split(".", 1)[1]: config.parse_value(v) for key, v in sets.items() if key.startswith("tracking.")}
    return replace(cfg, tracking=replace(cfg.tracking, **ts))


config.load_run_config = load
sys.argv = ["benchmarks/calibrate_disparity_offset.py"] + sys.argv[i + 1:]
runpy.run_path("benchmarks/calibrate_disparity_offset.py", run_name="__main__")
