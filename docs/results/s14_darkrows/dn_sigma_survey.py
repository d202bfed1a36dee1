#!/usr/bin/env python
"""The noise sigma ``auto``'s denoiser uses (measured after AFE's gain and the exposure curve) on every
left frame of each sequence given, with the synthetic config's enhancement; dark (``X>dn``) frames only.

    PYTHONPATH=$PWD python docs/results/s14_darkrows/dn_sigma_survey.py STEP DIR [DIR ...]
"""
import glob
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config  # noqa: E402
from canopy.enhance.auto import auto_treat  # noqa: E402
from canopy.enhance.noise import estimate_noise  # noqa: E402

p = load_run_config("synthetic").enhancement
step = int(sys.argv[1])
for d in sys.argv[2:]:
    files = sorted(glob.glob(d + "/mav0/cam0/data/*.png"))[::step]
    dn, raw, n = [], [], 0
    for f in files:
        im = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
        _, decision, sigma, _ = auto_treat(im, p)
        n += 1
        if decision.endswith(">dn"):
            dn.append(sigma)
            raw.append(estimate_noise(im, rows_fraction=0.5))
    if dn:
        print(f"{Path(d).name:48s} {len(dn)}/{n} frames X>dn: denoiser sigma {min(dn):.2f}-{max(dn):.2f} "
              f"(p50 {np.median(dn):.2f}), raw robust sigma {min(raw):.2f}-{max(raw):.2f}")
    else:
        print(f"{Path(d).name:48s} 0/{n} frames X>dn")
