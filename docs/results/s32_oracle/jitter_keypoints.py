#!/usr/bin/env python
"""s32: does keypoint position noise alone make the stereo path long? Clean KITTI 06 with the left
keypoints moved by whole pixels at their pyramid level (each coordinate: -1 / 0 / +1 with probability
p/2, 1-p, p/2), independently per frame; the stereo SAD then measures the disparity of the moved
keypoint's patch, so depths stay right for the pixel it names. Prints ATE, Sim(3) ATE and scale.

    PYTHONPATH=$PWD python docs/results/s32_oracle/jitter_keypoints.py --p 0.5 --seed 0 [--set tracking.x=v]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.frontend import Tracker  # noqa: E402
from oracle_common import run_cell, step_ratio  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--p", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[])
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    orig_init = Tracker.__init__

    def init(self, *a, **k):
        orig_init(self, *a, **k)
        ex = self.extractor
        orig_extract = ex.extract

        def extract(image, *ea, **ek):
            f = orig_extract(image, *ea, **ek)
            if args.p > 0 and len(f):
                step = rng.choice([-1.0, 0.0, 1.0], size=f.uv.shape, p=[args.p / 2, 1 - args.p, args.p / 2])
                scale = (self.params.scale_factor ** f.octave.astype(np.float64))[:, None]
                uv = f.uv + (step * scale).astype(np.float32)
                h, w = image.shape[:2]
                uv[:, 0] = np.clip(uv[:, 0], 0, w - 1)
                uv[:, 1] = np.clip(uv[:, 1], 0, h - 1)
                f.uv = uv
            return f
        ex.extract = extract
    Tracker.__init__ = init

    res, rows = run_cell(None, args.set)
    print(json.dumps({"p": args.p, "seed": args.seed, "ate_mm": res["ate"] * 1e3, "ate_sim3_mm": res["ate_sim3"] * 1e3,
                      "scale": res["scale"], "step_ratio": step_ratio(rows), "tracked": res["tracked"]}))


if __name__ == "__main__":
    main()
