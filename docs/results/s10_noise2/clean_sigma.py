# Robust noise sigma (the smoothed-refinement rule's measure, canopy.frontend.noisy_features.refinement_pair)
# of the clean presets' left frames as the tracker sees them (after the config's `auto` enhancement),
# every STEP-th frame. Usage: clean_sigma.py [STEP] — prints max / 99th percentile per preset.
import sys
from dataclasses import replace
import numpy as np
from canopy.config import load_run_config
from canopy.enhance import make_enhancer
from canopy.enhance.noise import estimate_noise
from benchmarks.bench_enhance_diagnose import enhance_pair
from canopy.sources import open_source
step = int(sys.argv[1]) if len(sys.argv) > 1 else 10
cfg = load_run_config("synthetic")
for preset in ("day-loop", "dusk-loop", "haze-row", "dark-rows"):
    src = open_source("euroc", f"/work/cache/synthetic/{preset}-seed0-full")
    enh = make_enhancer(cfg.enhancement)
    s, methods = [], {}
    for i in range(0, len(src), step):
        f = src.frame(i)
        le, _, info = enhance_pair(enh, f.left, f.right)
        methods[info["method"]] = methods.get(info["method"], 0) + 1
        s.append(estimate_noise(le, rows_fraction=0.5))
    s = np.array(s)
    print(f"{preset}: {len(s)} frames, robust sigma max {s.max():.2f} p99 {np.percentile(s, 99):.2f}, "
          f">= 4: {int((s >= 4).sum())}  {methods}")
