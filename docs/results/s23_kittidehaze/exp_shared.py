"""Forced agri / dehaze with the right image dehazed with the left image's A (SHARED=1) or its own (SHARED=0).
usage: exp_shared.py agri|dehaze [cells]"""
import os, sys
from _paths import CELLS, CLEAN, HERE, ORACLE_T, ROOT  # noqa: F401 (also puts the repo on sys.path)

import sys, os
import bench_enhance_diagnose as bed
from canopy.config import load_run_config
import cv2
import canopy.enhance.dehaze as dz
from canopy.enhance.dehaze import dehaze_inverted, dehaze_dark_channel, atmospheric_light, dark_channel


def pair_airlight(method, image, params):
    """A as ``method`` estimates it on ``image`` (agri: on the inverted image)."""
    q = cv2.bitwise_not(image) if method == "agri" else image
    return atmospheric_light(q, dark_channel(q, params.block), params.n_dark_pixels)


_estimate = dz.atmospheric_light


def with_airlight(fn, image, params, a):
    """``fn`` with its A estimate replaced by ``a`` (None: its own estimate)."""
    if a is None:
        return fn(image, params)
    dz.atmospheric_light = lambda *args: a
    try:
        return fn(image, params)
    finally:
        dz.atmospheric_light = _estimate
method = sys.argv[1]
shared = os.environ.get("SHARED", "1") == "1"
EP = load_run_config("kitti").enhancement
fn = dehaze_inverted if method == "agri" else dehaze_dark_channel
orig = bed.enhance_pair
def pair(enhancer, left, right):
    le, re, info = orig(enhancer, left, right)
    a = pair_airlight(method, left, EP)
    return with_airlight(fn, left, EP, a), with_airlight(fn, right, EP, a if shared else None), info
bed.enhance_pair = pair
cells = sys.argv[2:] or [f"kitti-all-g1-b0.06-{n}-seed{s}-stereo-sky" for n in ("low", "high") for s in (0, 1, 2)]
for c in cells:
    out, rows = bed.run(CELLS + "/" + c, CLEAN, "kitti",
                        {"method": "none"}, {}, None, stereo=False, kind="kitti")
    print(c, method, "shared" if shared else "own", round(100 * out["tracked"], 1), round(1e3 * out.get("ate", float("nan")), 1), flush=True)
