"""s33: Canopy auto on the generated presets' clean sequences, in process (the grid's runner), with this
folder's patches applied by with_patch.py:
    PYTHONPATH=$PWD python docs/results/s33_window/preset_clean.py [tracking.x=v ...]"""
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from benchmarks.bench_degrade_grid import run_canopy_in_process  # noqa: E402
from canopy.config import parse_value  # noqa: E402

FRAMES = {"day-loop": 300, "haze-row": 346, "dark-rows": 150}
settings = [tuple(k.split(".", 1)) + (parse_value(v),) for k, v in (a.split("=", 1) for a in sys.argv[1:])]
cache = Path(os.environ["CANOPY_CACHE_DIR"]) / "synthetic"
for preset, frames in FRAMES.items():
    clean = cache / f"{preset}-seed0-full"
    r = run_canopy_in_process(preset, clean, clean, "auto", frames, settings)
    print(f"{preset} clean: {r['ate_rmse_m'] * 1e3:.3f} mm, tracked {r['tracked_pct']:.1f} %", flush=True)
