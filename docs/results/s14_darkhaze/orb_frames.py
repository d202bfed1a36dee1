#!/usr/bin/env python
"""s14-darkhaze: ORB-SLAM3 on Canopy's enhanced frames (the grid's "orbslam3-auto"), per frame against
ground truth: the frame-to-frame rotation error, its yaw part and the translation error, as
diag_frames.py prints them for Canopy. Run:

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s14_darkhaze/orb_frames.py \
        /work/cache/degraded/kitti-all-g0.06-b0.06-low-seed0 [--raw]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_degrade_grid import pair_preprocess  # noqa: E402
from benchmarks.peers import orbslam3 as orb  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402


def rot_deg(R):
    return float(np.degrees(np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0))))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("path")
    ap.add_argument("--raw", action="store_true", help="ORB-SLAM3 on the raw degraded frames")
    a = ap.parse_args()
    src = open_source("kitti", a.path)
    gt = open_source("kitti", BUNDLED_DATA["kitti"]).ground_truth.poses
    res = orb.run_stereo(a.path, "kitti", preprocess=None if a.raw else pair_preprocess(), pace=False)
    stamps = np.asarray(src.timestamps)
    idx = [int(np.argmin(np.abs(stamps - s))) for s in res.trajectory.stamps]
    est = {i: P for i, P in zip(idx, res.trajectory.poses)}
    drots = []
    for i in sorted(est):
        if i - 1 in est:
            de, dg = se3_inv(est[i - 1]) @ est[i], se3_inv(gt[i - 1]) @ gt[i]
            E = se3_inv(dg) @ de
            d = rot_deg(E[:3, :3])
            drots.append(d)
            print(f"i={i} drot={d:.3f} dyaw={np.degrees(np.arctan2(E[0, 2], E[2, 2])):.3f} "
                  f"dtrans_mm={1000 * np.linalg.norm(E[:3, 3]):.1f}")
    ii = sorted(est)
    ate = ape(np.array([est[i] for i in ii]), gt[ii], "se3")["rmse"] if len(ii) > 2 else float("nan")
    print(f"SUMMARY {Path(a.path).name} raw={a.raw} tracked={100 * len(ii) / len(src):.1f} % ate_mm={1000 * ate:.1f} "
          f"drot_med={np.median(drots):.4f} drot_rms={np.sqrt(np.mean(np.square(drots))):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
