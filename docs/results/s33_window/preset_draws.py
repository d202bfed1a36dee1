"""s33: Canopy auto on a generated preset's degraded cell over noise draws, in process (the grid's runner):
    PYTHONPATH=$PWD python docs/results/s33_window/preset_draws.py day-loop 300 g0.15-b0.06-high-{s}-rendered 0 1 2
prints one line per draw and the draws' summary (ATE mm, tracked %)."""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from benchmarks.bench_degrade_grid import run_canopy_in_process  # noqa: E402
import os  # noqa: E402

preset, frames, pattern, seeds = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4:]
cache = Path(os.environ["CANOPY_CACHE_DIR"])
clean = cache / "synthetic" / f"{preset}-seed0-full"
ates = []
for s in seeds:
    cell = cache / "degraded" / f"{preset}-{frames}-{pattern.replace('{s}', 'seed' + s)}"
    r = run_canopy_in_process(preset, cell, clean, "auto", frames)
    ates.append(r["ate_rmse_m"] * 1e3)
    print(f"{cell.name}: {ates[-1]:.2f} mm, tracked {r['tracked_pct']:.1f} %", flush=True)
print(f"{preset} {pattern}: median {np.median(ates):.1f}, mean {np.mean(ates):.1f} mm over {len(ates)} draws")
