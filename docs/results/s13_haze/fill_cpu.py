#!/usr/bin/env python
"""s13-haze: thread CPU of the stereo matching with and without the flow fill-in (load-robust:
time.thread_time) on every 5th frame of a cell, the tracker's extractor and the KITTI config.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s13_haze/fill_cpu.py <cell dir>
"""
import sys
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

cv2.setNumThreads(1)  # every cost on this thread (thread_time sees no OpenCV worker threads)

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.noisy_features import tracking_extractor  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.frontend.track_health import image_noise_sigma  # noqa: E402
from canopy.sources import open_source  # noqa: E402

on = replace(load_run_config("kitti").tracking, parallel_extraction=False)
off = replace(on, stereo_fill=False)
src = open_source("kitti", sys.argv[1])
ex_l, ex_r = tracking_extractor(on, responses=False), tracking_extractor(on, responses=False)
t_on, t_off, n_on, n_off = [], [], [], []
for i in range(0, len(src), 5):
    f = src.frame(i)
    ns = image_noise_sigma(f.left)
    fl, fr = ex_l.extract(f.left, noise_sigma=ns), ex_r.extract(f.right)
    for p, t, n in ((off, t_off, n_off), (on, t_on, n_on)):
        c = time.thread_time()
        st = match_stereo(fl, fr, f.left, f.right, src.calibration, p, ns)
        t.append(1e3 * (time.thread_time() - c))
        n.append(int(st.valid.sum()))
print(Path(sys.argv[1]).name, f"stereo CPU ms p50 off {np.median(t_off):.1f} on {np.median(t_on):.1f}; "
      f"matches p50 off {np.median(n_off):.0f} on {np.median(n_on):.0f}")
