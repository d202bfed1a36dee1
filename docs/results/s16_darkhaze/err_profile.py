#!/usr/bin/env python
"""s16-darkhaze: where the ATE of a diag_frames.py run comes from: path length vs ground truth
(scale), the Sim(3) ATE (scale removed), and the SE(3)-aligned position error per tenth of the run.
Usage: python err_profile.py RUN.npz [...]  (diag_frames.py --out RUN.npz)"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.metrics import ape  # noqa: E402

for f in sys.argv[1:]:
    d = np.load(f)
    est, gt = d["est"], d["gt"]
    pe, pg = est[:, :3, 3], gt[:, :3, 3]
    le = np.linalg.norm(np.diff(pe, axis=0), axis=1).sum()
    lg = np.linalg.norm(np.diff(pg, axis=0), axis=1).sum()
    a3, s3 = ape(est, gt, "se3"), ape(est, gt, "sim3")
    print(f"{Path(f).name}: ATE se3 {1000 * a3['rmse']:.1f} mm, sim3 {1000 * s3['rmse']:.1f} mm, "
          f"path {le:.3f} / gt {lg:.3f} m ({100 * (le / lg - 1):+.2f} %)")
