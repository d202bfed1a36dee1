#!/usr/bin/env python
"""s32 oracle: which part of the stereo error on a degraded KITTI cell costs the trajectory?

Runs the grid's in-process loop (bench_enhance_diagnose.run) on one cell with ``refine_and_accept``
wrapped: every accepted match is re-measured on the *clean* pair (centre SAD, raw pair, +-2 px around the
degraded result) and then, by ``--mode``:

  none      unchanged (the baseline, must reproduce the grid's figure)
  clean     the disparity replaced by the clean pair's (matches > 1 px off it dropped)
  debias    the degraded disparity minus its band's mean error (bias only removed; band means measured
            on this run's own matches against the clean pair, two passes)
  drop      matches > 1 px off the clean pair dropped, the others unchanged (outliers only removed)

Scratch experiment (uses ground-truth images), not a method. Prints a JSON line.
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
from oracle_common import clean_disparity, run_cell  # noqa: E402

BANDS = np.array([0, 3, 5, 8, 12, 20, 40, 1e9])
STATE = {"i": None, "errs": []}


def band_of(d):
    return np.clip(np.searchsorted(BANDS, d, side="right") - 1, 0, len(BANDS) - 2)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cell", required=True)
    ap.add_argument("--mode", choices=["none", "clean", "drop", "debias"], default="none")
    ap.add_argument("--bias", default=None, help="JSON of band means (debias / spread)")
    ap.add_argument("--method", default="auto")
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args()
    clean_path = BUNDLED_DATA["kitti"]
    clean = open_source("kitti", clean_path)
    bias = np.array(json.load(open(args.bias))["band_mean"]) if args.bias else np.zeros(len(BANDS) - 1)

    orig_track = Tracker.track

    def track(self, frame, *a, **k):
        STATE["i"] = frame.index
        return orig_track(self, frame, *a, **k)
    Tracker.track = track
    orig = stereo.refine_and_accept

    def wrapped(ref_left, ref_right, left, li, ur0, scale_factors, max_disp, params, noise_sigma, pyramids=None,
                normalise=None, raw_pair=None):
        li, ur, disp = orig(ref_left, ref_right, left, li, ur0, scale_factors, max_disp, params, noise_sigma,
                            pyramids, normalise, raw_pair)
        if len(li) == 0:
            return li, ur, disp
        uvl = left.uv[li].astype(np.float64)
        dc, okc = clean_disparity(clean.frame(STATE["i"]), left, li, ur, params, scale_factors)
        err = disp - dc
        good = okc & (np.abs(err) <= 1.0)
        STATE["errs"].append(np.stack([dc[good], err[good]], 1))
        STATE.setdefault("n", [0, 0])
        STATE["n"][0] += len(li); STATE["n"][1] += int(good.sum())
        if args.mode == "none":
            return li, ur, disp
        if args.mode == "clean":
            new = dc
        elif args.mode == "drop":
            new = disp
        elif args.mode == "debias":
            new = disp - bias[band_of(dc)]
        keep = good & (new > params.min_disparity)
        new = new[keep]
        return li[keep], uvl[keep, 0] - new, new
    stereo.refine_and_accept = wrapped

    res, rows = run_cell(args.cell, args.set, args.method)
    decisions = {}
    for r in rows:
        decisions[r["method"]] = decisions.get(r["method"], 0) + 1
    E = np.concatenate(STATE["errs"]) if STATE["errs"] else np.zeros((0, 2))
    b = band_of(E[:, 0])
    band_mean = [float(E[b == k, 1].mean()) if (b == k).any() else 0.0 for k in range(len(BANDS) - 1)]
    band_sd = [float(E[b == k, 1].std()) if (b == k).any() else 0.0 for k in range(len(BANDS) - 1)]
    band_n = [int((b == k).sum()) for k in range(len(BANDS) - 1)]
    out = {"cell": Path(args.cell).name, "mode": args.mode, "ate_mm": res.get("ate", float("nan")) * 1000,
           "ate_sim3_mm": res.get("ate_sim3", float("nan")) * 1000, "scale": res.get("scale"),
           "tracked": 100 * res["tracked"], "decisions": decisions, "matches": STATE["n"][0],
           "within_1px": STATE["n"][1] / max(STATE["n"][0], 1), "bands": BANDS[:-1].tolist(),
           "band_mean": band_mean, "band_sd": band_sd, "band_n": band_n}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
