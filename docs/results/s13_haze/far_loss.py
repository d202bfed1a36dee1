#!/usr/bin/env python
"""s13-haze: where the far points are lost on a hazy frame: keypoints, stereo matches, by the clean
SGBM depth of their pixel (bins < 10, 10-20, 20-30, > 30 m), on every 10th frame.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s13_haze/far_loss.py <cell dir> [tracking.name=value ...]
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config, parse_value  # noqa: E402
from far_frames import frames_against_clean  # noqa: E402

cfg = load_run_config("kitti")
sets = {k.split(".", 1)[1]: parse_value(v) for k, v in (a.split("=", 1) for a in sys.argv[2:])}
tp = replace(cfg.tracking, **sets)
edges = [0, 10, 20, 30, 1e9]
tot = np.zeros((3, 4))
for i, tr, fl, frr, st, d in frames_against_clean(sys.argv[1], cfg, tp):
    bf = tr.calib.bf
    uv = fl.uv
    z = np.where(d > 0, bf / np.maximum(d, 1e-6), np.nan)
    zb = np.digitize(z, edges[1:-1])
    kp = [int(((zb == b) & np.isfinite(z)).sum()) for b in range(4)]
    sv = [int(((zb == b) & np.isfinite(z) & st.valid).sum()) for b in range(4)]
    # stereo error of valid matches per bin (px)
    err = np.abs((uv[:, 0] - st.u_right) - d)
    bad = [int(((zb == b) & np.isfinite(z) & st.valid & (err > 1)).sum()) for b in range(4)]
    tot += np.array([kp, sv, bad])
    print(f"frame {i:2d} kp {len(fl)} by depth <10/10-20/20-30/>30: kp {kp} stereo {sv} stereo>1px off {bad}")
print("total kp", tot[0].astype(int).tolist(), "stereo", tot[1].astype(int).tolist(), "bad", tot[2].astype(int).tolist())
