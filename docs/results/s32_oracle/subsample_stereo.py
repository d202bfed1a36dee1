#!/usr/bin/env python
"""s32: clean KITTI 06 with a random ``--drop`` fraction of the accepted stereo matches removed per frame (one draw
per ``--seed``): how much does the path's scale move with *which* clean disparities the tracker gets?

    PYTHONPATH=$PWD python docs/results/s32_oracle/subsample_stereo.py --drop 0.2 --seed 0
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
from canopy.frontend.keypoint_uncertainty import row_gradient_energy  # noqa: E402
from oracle_common import run_cell  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--drop", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--far-only", type=float, default=0.0, help="drop only matches with disparity below this (px)")
    ap.add_argument("--keep-contrast", choices=["random", "high", "low"], default="random",
                    help="drop the --drop fraction with the lowest (high: keep the high) or highest row-gradient "
                         "energy per window pixel (keypoint_uncertainty.row_gradient_energy) instead of at random")
    ap.add_argument("--near-only", type=float, default=0.0, help="drop only matches with disparity above this (px)")
    ap.add_argument("--set", action="append", default=[], help="tracking.field=value")
    ap.add_argument("--preset-path", default=None, help="a generated sequence folder (synthetic config) instead of KITTI")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--band-quantile", type=float, default=0.0,
                    help="> 0: --near-only / --far-only thresholds become this per-frame disparity quantile (far: 1 - q)")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    orig = stereo.refine_and_accept

    def wrapped(*a, **k):
        li, ur, disp = orig(*a, **k)
        if args.keep_contrast != "random" and len(li):
            ref_left, left, params, sf = a[0], a[2], a[7], a[5]
            sxx, n = row_gradient_energy(ref_left, left.uv[li].astype(np.float64), sf[left.octave[li]],
                                         params.subpixel_window)
            e = sxx / n if args.keep_contrast == "high" else -sxx / n
            keep = e >= np.quantile(e, args.drop)
            return li[keep], ur[keep], disp[keep]
        keep = rng.random(len(li)) >= args.drop
        far_t, near_t = args.far_only, args.near_only
        if args.band_quantile > 0 and len(disp):
            far_t = np.quantile(disp, args.band_quantile) if args.far_only > 0 else 0
            near_t = np.quantile(disp, 1 - args.band_quantile) if args.near_only > 0 else 0
        if far_t > 0:
            keep |= disp >= far_t
        if near_t > 0:
            keep |= disp <= near_t
        return li[keep], ur[keep], disp[keep]
    stereo.refine_and_accept = wrapped
    if args.preset_path:
        res, _ = run_cell(args.preset_path, args.set, config="synthetic", kind="euroc", max_frames=args.max_frames)
    else:
        res, _ = run_cell(None, args.set, max_frames=args.max_frames)
    print(json.dumps({"drop": args.drop, "far_only": args.far_only, "near_only": args.near_only, "keep_contrast": args.keep_contrast, "set": args.set, "seed": args.seed, "ate_mm": res["ate"] * 1e3,
                      "ate_sim3_mm": res["ate_sim3"] * 1e3, "scale": res["scale"]}))


if __name__ == "__main__":
    main()
