#!/usr/bin/env python
"""s32 oracle: the *clean* KITTI run (clean frames, clean features, clean stereo, clean gates) whose stereo matches
are restricted to the left keypoints that the degraded cell's pair also matches (within 1 px of the clean
disparity): the degraded frames only choose *which* clean depths the tracker gets. The degraded pair's stereo is
measured with the left keypoints of the clean image, right keypoints extracted from the degraded (enhanced) right
image with the FAST arguments the enhancement rule hands it, and the degraded pair's images. Scratch experiment.

    PYTHONPATH=$PWD python docs/results/s32_oracle/oracle_selection.py --cell CELL
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import canopy.frontend.tracker_worker as tw  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.cell_extractor import make_extractor  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402
from oracle_common import run_cell  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cell", required=True)
    ap.add_argument("--select", choices=["degraded", "none"], default="degraded")
    ap.add_argument("--set", action="append", default=[], help="tracking.field=value")
    args = ap.parse_args()
    clean = open_source("kitti", BUNDLED_DATA["kitti"])
    state = {}
    orig_track = Tracker.track

    def track(self, frame, *a, **k):
        state["degraded"], state["kw"] = frame, k
        if "ex_r" not in state:
            state["ex_r"] = make_extractor(self.params)
        c = clean.frame(frame.index)
        return orig_track(self, StereoFrame(frame.index, frame.timestamp, c.left, c.right), *a)
    Tracker.track = track
    orig_match = tw.match_stereo
    stats = {"clean": 0, "kept": 0}

    def match(left, right, left_img, right_img, calib, params, *a, **k):
        st = orig_match(left, right, left_img, right_img, calib, params, *a, **k)
        if args.select == "none":
            return st
        deg, kw = state["degraded"], state["kw"]
        fast = {kk: kw[kk] for kk in ("fast_threshold", "fast_fallback", "fast_min_keypoints") if kk in kw}
        right_deg = state["ex_r"].extract(deg.right, fast.get("fast_threshold"), fast.get("fast_fallback"),
                                          fast.get("fast_min_keypoints", 0))
        sd = orig_match(left, right_deg, deg.left, deg.right, calib, params)
        ok_c, ok_d = st.u_right >= 0, sd.u_right >= 0
        keep = ok_c & ok_d & (np.abs(st.u_right - sd.u_right) <= 1.0)
        stats["clean"] += int(ok_c.sum())
        stats["kept"] += int(keep.sum())
        st.u_right[~keep] = -1.0
        st.depth[~keep] = -1.0
        return st
    tw.match_stereo = match
    res, _ = run_cell(args.cell, args.set)
    print(json.dumps({"cell": Path(args.cell).name, "select": args.select, "set": args.set, "ate_mm": res["ate"] * 1e3,
                      "ate_sim3_mm": res["ate_sim3"] * 1e3, "scale": res["scale"],
                      "kept_fraction": stats["kept"] / max(stats["clean"], 1)}))


if __name__ == "__main__":
    main()
