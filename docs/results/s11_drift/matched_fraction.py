# StereoBM's matched fraction (the contour test's frame gate, tracking.contour_min_matched_fraction) on
# the auto-enhanced pairs of clean presets and degraded cells, every STEP-th frame, no tracking.
# Usage: matched_fraction.py STEP CELL|PRESET-clean [...]
import sys
from dataclasses import replace
import numpy as np
from benchmarks.bench_enhance_diagnose import enhance_pair
from canopy.config import load_run_config
from canopy.enhance import make_enhancer
from canopy.frontend.stereo_silhouette import ContourParams, SilhouetteDetector
from canopy.sources import open_source

step = int(sys.argv[1])
cfg = load_run_config("synthetic")
det = SilhouetteDetector(ContourParams())
for cell in sys.argv[2:]:
    preset = cell.split("-")[0] + "-" + cell.split("-")[1]
    path = f"/work/cache/synthetic/{preset}-seed0-full" if cell.endswith("-clean") else f"/work/cache/degraded/{cell}"
    src = open_source("euroc", path)
    enh = make_enhancer(replace(cfg.enhancement, method="auto"))
    fr = []
    for i in range(0, len(src), step):
        f = src.frame(i)
        le, re, info = enhance_pair(enh, f.left, f.right)
        d, first = det.disparity(le, re)
        fr.append(det.matched_fraction(d, first))
    fr = np.array(fr)
    print(f"{cell:48s} n={len(fr):4d} matched fraction min {fr.min():.2f} p5 {np.percentile(fr, 5):.2f} "
          f"median {np.median(fr):.2f} max {fr.max():.2f}", flush=True)
