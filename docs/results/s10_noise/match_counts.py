"""Stereo matches kept per frame, raw vs smoothed refinement, on noisy preset cells (s10-noise probe)."""
import sys
from dataclasses import replace
import numpy as np
from canopy.config import load_run_config
from canopy.frontend.features import OrbExtractor
from canopy.frontend.stereo import match_stereo
from canopy.sources import open_source
base = replace(load_run_config("synthetic").tracking, parallel_extraction=False, subpixel_denoise_sigma=0.0)
for cell in sys.argv[1:]:
    s = open_source("euroc", f"/work/cache/degraded/{cell}")
    n = {0: 0, 1.5: 0, 2.0: 0}
    for i in range(10, 300, 30):
        f = s.frame(i)
        fl, fr = OrbExtractor(base).extract(f.left), OrbExtractor(base).extract(f.right)
        for b in n:
            p = base if b == 0 else replace(base, subpixel_denoise_sigma=4.0, subpixel_denoise_blur=b)
            n[b] += int(match_stereo(fl, fr, f.left, f.right, s.calibration, p).valid.sum())
    print(cell, n)
