#!/usr/bin/env python
"""s32 oracle: on a degraded KITTI cell, extract the left image's features (positions and descriptors) on the
*clean* left frame instead (``--left-features clean``), optionally with the stereo disparities from the clean pair
as well (``--disparity clean``, oracle_stereo.py's rule); everything else (right features, stereo SAD, gates)
runs on the degraded, enhanced frames. Scratch experiment (ground-truth images), not a method.

    PYTHONPATH=$PWD python docs/results/s32_oracle/oracle_features.py --cell CELL [--left-features clean]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import canopy.frontend.stereo as stereo  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from oracle_common import clean_disparity, run_cell, step_ratio  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cell", required=True)
    ap.add_argument("--left-features", choices=["degraded", "clean"], default="degraded")
    ap.add_argument("--disparity", choices=["degraded", "clean"], default="degraded")
    ap.add_argument("--clean-args", choices=["cell", "none"], default="cell",
                    help="the clean left image's extraction with the FAST arguments handed for the cell's enhanced "
                         "frame (cell) or with none, as the clean run extracts (none)")
    ap.add_argument("--method", default="auto")
    ap.add_argument("--set", action="append", default=[], help="tracking.field=value / mapping.field=value")
    args = ap.parse_args()
    clean_path = BUNDLED_DATA["kitti"]
    clean = open_source("kitti", clean_path)
    state = {"i": None}
    orig_track = Tracker.track

    def track(self, frame, *a, **k):
        state["i"] = frame.index
        state["left"] = frame.left
        return orig_track(self, frame, *a, **k)
    Tracker.track = track
    orig_init = Tracker.__init__

    def init(self, *a, **k):
        orig_init(self, *a, **k)
        ex = self.extractor
        orig_extract = ex.extract

        def extract(image, *ea, **ek):
            if args.left_features == "degraded" or image is not state.get("left"):
                return orig_extract(image, *ea, **ek)
            if args.clean_args == "none":
                ea, ek = (), {}
            fc = orig_extract(clean.frame(state["i"]).left, *ea, **ek)
            return fc
        ex.extract = extract
    Tracker.__init__ = init

    if args.disparity == "clean":
        orig = stereo.refine_and_accept

        def wrapped(ref_left, ref_right, left, li, ur0, scale_factors, max_disp, params, noise_sigma, pyramids=None,
                    normalise=None, raw_pair=None):
            li, ur, disp = orig(ref_left, ref_right, left, li, ur0, scale_factors, max_disp, params, noise_sigma,
                                pyramids, normalise, raw_pair)
            if len(li) == 0:
                return li, ur, disp
            uvl = left.uv[li].astype(np.float64)
            dc, okc = clean_disparity(clean.frame(state["i"]), left, li, ur, params, scale_factors)
            keep = okc & (np.abs(disp - dc) <= 1.0) & (dc > params.min_disparity)
            return li[keep], uvl[keep, 0] - dc[keep], dc[keep]
        stereo.refine_and_accept = wrapped

    res, rows = run_cell(args.cell, args.set, args.method)
    print(json.dumps({"cell": Path(args.cell).name, "left_features": args.left_features, "disparity": args.disparity, "clean_args": args.clean_args, "set": args.set,
                      "ate_mm": res["ate"] * 1e3, "ate_sim3_mm": res["ate_sim3"] * 1e3, "scale": res["scale"],
                      "step_ratio": step_ratio(rows), "tracked": res["tracked"]}))


if __name__ == "__main__":
    main()
