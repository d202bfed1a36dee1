"""CPU time (process_time: all threads, load-robust) of the enhancement of one stereo pair with the
synthetic config, on a clean and on a noisy lit generated pair (minimum and median of 40 calls).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s11_haze/lit_denoise_cpu.py
"""
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config  # noqa: E402
from canopy.enhance.pair import PairEnhancer  # noqa: E402
from canopy.sources import open_source  # noqa: E402

CELLS = {"clean day-loop": "/work/cache/synthetic/day-loop-seed0-full",
         "day-loop g1-b0-high": "/work/cache/degraded/day-loop-300-g1-b0-high-seed0",
         "haze-row g1-b0.06-high": "/work/cache/degraded/haze-row-346-g1-b0.06-high-seed0-rendered",
         "dark-rows g1-b0-high": "/work/cache/degraded/dark-rows-150-g1-b0-high-seed0"}   # the dark branch, for comparison

enh = PairEnhancer(load_run_config("synthetic").enhancement)
for name, path in CELLS.items():
    f = open_source("euroc", path, max_frames=20).frame(10)
    cpu = []
    for _ in range(40):
        t = time.process_time()
        _, _, info = enh(f.left, f.right)
        cpu.append((time.process_time() - t) * 1e3)
    print(f"{name:<24} {info['method']:<8} CPU per pair: min {min(cpu):.2f} ms, median {np.median(cpu):.2f} ms")
