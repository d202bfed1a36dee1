"""Dehaze with the exact painted transmission and A = 220 (an oracle): J = (I − A)/max(t, t0) + A on both views.
usage: oracle_exp.py t0 [cells]"""
import os, sys
from _paths import CELLS, CLEAN, HERE, ORACLE_T, ROOT  # noqa: F401 (also puts the repo on sys.path)

import sys, os
import numpy as np
import bench_enhance_diagnose as bed
from dehaze_guided import remove_haze
t0 = float(sys.argv[1])
T = np.load(ORACLE_T)
TL, TR = T["left"], T["right"]
state = {"i": 0}
orig = bed.enhance_pair
def pair(enhancer, left, right):
    le, re, info = orig(enhancer, left, right)
    i = state["i"]; state["i"] += 1
    return (remove_haze(left, TL[i] / 255.0, 220.0, t0), remove_haze(right, TR[i] / 255.0, 220.0, t0), info)
bed.enhance_pair = pair
cells = sys.argv[2:] or [f"kitti-all-g1-b0.06-{n}-seed{s}-stereo-sky" for n in ("low", "high") for s in (0, 1, 2)]
for c in cells:
    state["i"] = 0
    out, rows = bed.run(CELLS + "/" + c, CLEAN, "kitti",
                        {"method": "none"}, {}, None, stereo=False, kind="kitti")
    print(c, "t0", t0, round(100 * out["tracked"], 1), round(1e3 * out.get("ate", float("nan")), 1), flush=True)
