#!/usr/bin/env python
"""Frame-by-frame diagnosis of the in-process tracking + local mapping loop against ground truth.

Runs ``canopy.pipeline.run_sequential`` with a dataset's shipped config (the same parameters
the actors use) and prints ATE (SE(3)-aligned), path-length error, keyframe count, tracking
time p50, and per-frame translation of the estimated vs ground-truth motion (the scale
ratio |t_est| / |t_gt| shows a depth bias: > 1 means motion over-estimated).

    PYTHONPATH=$PWD python benchmarks/diagnose_tracking.py --dataset kitti [--per-frame] [--set tracking.x=1] [--lines]
    PYTHONPATH=$PWD python benchmarks/diagnose_tracking.py --dataset synthetic \
        --path /work/cache/synthetic/day-loop-seed0-full      # a generated sequence (EuRoC layout)
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config, parse_setting, with_overrides, with_settings  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import run_sequential  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def run(dataset: str, path=None, max_frames=None, sets=(), lines=False):
    """In-process lockstep run with the dataset's config and ``section.name=value`` overrides."""
    cfg = with_settings(with_overrides(load_run_config(dataset), lines=lines or None),
                        [parse_setting(s) for s in sets])
    tp, mp = cfg.tracking, cfg.mapping
    # generated sequences are EuRoC folders with their own config (configs/synthetic.yaml)
    src = open_source("euroc" if dataset == "synthetic" else dataset, path, max_frames=max_frames)
    res = run_sequential(src, tp, mp, map_update_lag=cfg.runtime.map_update_lag_frames)  # as the actors
    return src, res


def per_frame_table(est: np.ndarray, gt: np.ndarray) -> list[dict]:
    rows = []
    for i in range(1, len(est)):
        de = se3_inv(est[i - 1]) @ est[i]
        dg = se3_inv(gt[i - 1]) @ gt[i]
        te, tg = np.linalg.norm(de[:3, 3]), np.linalg.norm(dg[:3, 3])
        rows.append({"i": i, "t_est": te, "t_gt": tg, "ratio": te / tg if tg > 1e-6 else float("nan"),
                     "dt_err": float(np.linalg.norm(de[:3, 3] - dg[:3, 3]))})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--path", default=None)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--set", action="append", default=[], help="section.name=value parameter override")
    ap.add_argument("--lines", action="store_true")
    ap.add_argument("--per-frame", action="store_true")
    args = ap.parse_args()
    src, res = run(args.dataset, args.path, args.max_frames, args.set, args.lines)
    gt = src.ground_truth.poses[: res.n_frames]
    est = res.trajectory.poses
    a = ape(est, gt, align="se3")
    a_sim3 = ape(est, gt, align="sim3")
    pl_e, pl_g = res.trajectory.path_length(), float(np.sum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)))
    ts = res.timing_summary()
    rows = per_frame_table(est, gt)
    ratio = np.array([r["ratio"] for r in rows if r["t_gt"] > 0.05])
    print(f"ATE {a['rmse']:.4f} m (sim3 {a_sim3['rmse']:.4f})  path {pl_e:.2f}/{pl_g:.2f} m ({100 * (pl_e / pl_g - 1):+.2f} %)  "
          f"kf {len(res.keyframe_indices)}/{res.n_frames}  lost {res.n_lost}  "
          f"median motion ratio {np.median(ratio) if len(ratio) else float('nan'):.4f}  "
          f"track p50 {ts['tracking.total']['p50']:.1f} ms  ba p50 {ts.get('mapping.ba', {}).get('p50', 0):.1f} ms  "
          f"map lines {len(res.map_lines)}")
    if args.per_frame:
        for r in rows:
            print(f"{r['i']:4d} est {r['t_est']:.3f} gt {r['t_gt']:.3f} ratio {r['ratio']:.3f} err {r['dt_err']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
