"""Far disparity excess of the tracker's stereo matches vs the clean pair's SGBM disparity, per treatment.
usage: bias.py CELL treatment[,omega,t0] ..."""
import os, sys
from _paths import CELLS, CLEAN, HERE, ORACLE_T, ROOT  # noqa: F401 (also puts the repo on sys.path)

import sys, types, numpy as np
from dataclasses import replace
from canopy.config import load_run_config
from canopy.degrade import disparity_sgbm
from canopy.frontend import Tracker
from canopy.frontend.stereo import match_stereo
from canopy.sources import open_source
cell = sys.argv[1]
cfg = load_run_config("kitti")
src = open_source("kitti", CELLS + "/" + cell)
clean = open_source("kitti", CLEAN)
fb = src.calibration.fx * src.calibration.baseline if hasattr(src.calibration, "baseline") else None
refs = {}
import os
ORACLE = np.load(ORACLE_T)
from dehaze_guided import dehaze_guided, dehaze_guided_airlight
for spec in sys.argv[2:]:
    parts = spec.split(",")
    tr = Tracker(src.calibration, cfg.tracking)
    errs, ds = [], []
    for i in range(0, len(src), 5):
        fr = src.frame(i)
        l, r = fr.left, fr.right
        if parts[0] == "guided":
            p = types.SimpleNamespace(guided_omega=float(parts[1]), guided_radius=16, guided_eps=1e-3,
                                      guided_t0=float(parts[2]), auto_downsample=4, n_dark_pixels=200)
            a = dehaze_guided_airlight(l, p)
            l, r = dehaze_guided(l, p, a), dehaze_guided(r, p, a)
        elif parts[0] == "oracle":
            from dehaze_guided import remove_haze
            T = ORACLE
            l, r = remove_haze(l, T["left"][i] / 255.0, 220.0, float(parts[1])), remove_haze(r, T["right"][i] / 255.0, 220.0, float(parts[1]))
        elif parts[0] == "clean":
            c = clean.frame(i); l, r = c.left, c.right
        if i not in refs:
            c = clean.frame(i)
            d = disparity_sgbm(c.left, c.right).astype(np.float64); d[d <= 0] = -1; refs[i] = d
        ref = refs[i]
        fl = tr.extractor.extract(l, None, None, 0)
        frr = tr.extractor_right.extract(r, None, None, 0)
        st = match_stereo(fl, frr, l, r, tr.calib, tr.params)
        ok = st.valid
        uv = fl.uv[ok]; d_est = uv[:, 0] - st.u_right[ok]
        h, w = ref.shape
        d_ref = ref[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
        s = d_ref > 0
        errs.append(d_est[s] - d_ref[s]); ds.append(d_ref[s])
    e, d = np.concatenate(errs), np.concatenate(ds)
    # KITTI 06: fx*b ~ 707*0.537 = 380 px·m
    out = [spec, f"matches/frame {len(e)/len(errs):.0f}"]
    for lo, hi, name in ((380/10, 1e9, "<10m"), (380/20, 380/10, "10-20m"), (380/40, 380/20, "20-40m"), (0, 380/40, ">40m")):
        m = (d >= lo) & (d < hi)
        good = m & (np.abs(e) <= 3)
        out.append(f"{name}: n {m.sum()} med {np.median(e[m]) if m.any() else np.nan:+.2f} |e|<=3 med {np.median(e[good]) if good.any() else np.nan:+.3f}")
    print(" | ".join(out), flush=True)
