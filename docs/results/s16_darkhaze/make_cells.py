#!/usr/bin/env python
"""s16-darkhaze: write degraded cells as the grid would (same folder names) without running SLAM.
Usage: make_cells.py DATASET MAX_FRAMES "GAINS" "BETAS" NOISE "SEEDS" OUT_DIR"""
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
from bench_degrade_grid import cell_haze_depth, degraded_cell, sequence_path  # noqa: E402
from canopy.degrade import grid_cells  # noqa: E402

d, mf, gains, betas, noise, seeds, out = sys.argv[1:8]
cache = Path(os.environ.get("CANOPY_CACHE_DIR", "cache"))
kind, clean_path = sequence_path(d, cache)
for s in seeds.split():
    for cell in grid_cells(tuple(float(g) for g in gains.split()), tuple(float(b) for b in betas.split()),
                           (noise,), seed=int(s)):
        hd = cell_haze_depth("auto", d, kind, clean_path)
        path, _ = degraded_cell(kind, d, clean_path, cell, None if mf == "all" else int(mf), Path("/tmp"), Path(out), hd)
        print(path, flush=True)
