#!/usr/bin/env python
"""s32: benchmarks/calibrate_disparity_offset.py --method map on clean KITTI with the stereo matches restricted to
the high- or low-contrast part (row-gradient energy per window pixel, per frame) -- is the offset the map sees
different for high- and low-contrast patches?

    PYTHONPATH=$PWD python docs/results/s32_oracle/calibrate_by_contrast.py high 0.37 [calibrate args...]
"""
import runpy
import sys

import numpy as np

import canopy.frontend.stereo as stereo
from canopy.frontend.keypoint_uncertainty import row_gradient_energy

which, drop = sys.argv[1], float(sys.argv[2])
orig = stereo.refine_and_accept


def wrapped(*a, **k):
    li, ur, disp = orig(*a, **k)
    if len(li) == 0:
        return li, ur, disp
    ref_left, left, sf, params = a[0], a[2], a[5], a[7]
    sxx, n = row_gradient_energy(ref_left, left.uv[li].astype(np.float64), sf[left.octave[li]], params.subpixel_window)
    e = sxx / n if which == "high" else -sxx / n
    keep = e >= np.quantile(e, drop)
    return li[keep], ur[keep], disp[keep]


stereo.refine_and_accept = wrapped
sys.argv = ["benchmarks/calibrate_disparity_offset.py"] + sys.argv[3:]
runpy.run_path("benchmarks/calibrate_disparity_offset.py", run_name="__main__")
