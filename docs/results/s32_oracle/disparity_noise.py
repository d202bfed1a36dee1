#!/usr/bin/env python
"""s32: does zero-mean disparity noise alone make the stereo path long (Jensen: E[bf/d] > bf/E[d])?
Clean KITTI 06 (or a cell with ``--cell``) with Gaussian noise of ``--sigma`` px (times ``--scale-by-octave``'s
s^octave when set) added to every accepted stereo disparity, one draw per ``--seed``. Prints ATE, Sim(3) ATE, scale.
Scratch experiment, not a method."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import canopy.frontend.stereo as stereo  # noqa: E402
from oracle_common import run_cell, step_ratio  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sigma", type=float, default=0.3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cell", default=None)
    ap.add_argument("--scale-by-octave", action="store_true")
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    orig = stereo.refine_and_accept

    def wrapped(ref_left, ref_right, left, li, ur0, scale_factors, max_disp, params, noise_sigma, pyramids=None,
                normalise=None, raw_pair=None):
        li, ur, disp = orig(ref_left, ref_right, left, li, ur0, scale_factors, max_disp, params, noise_sigma,
                            pyramids, normalise, raw_pair)
        if len(li) == 0 or args.sigma <= 0:
            return li, ur, disp
        s = args.sigma * (scale_factors[left.octave[li]] if args.scale_by_octave else 1.0)
        new = disp + rng.normal(0.0, 1.0, len(li)) * s
        keep = new > params.min_disparity
        return li[keep], left.uv[li[keep], 0] - new[keep], new[keep]
    stereo.refine_and_accept = wrapped
    res, rows = run_cell(args.cell, args.set)
    print(json.dumps({"sigma": args.sigma, "seed": args.seed, "octave": args.scale_by_octave, "set": args.set,
                      "ate_mm": res["ate"] * 1e3, "ate_sim3_mm": res["ate_sim3"] * 1e3, "scale": res["scale"],
                      "step_ratio": step_ratio(rows)}))


if __name__ == "__main__":
    main()
