#!/usr/bin/env python
"""s32: is the rig's disparity error a field over the image rather than one constant? The whole map's bundle
adjustment of an in-process clean KITTI run (canopy.backend.map_offset, GT-free) profiled over a 2-D grid: every
stereo observation's disparity shifted by d0 + dv * (v - cy) / H + du * (u - cx) / W (``--axis v`` or ``u``).
A rectification residual (the right camera rolled by theta: du_r = -theta (v - cy); a focal-length mismatch: a
term in u - cx) gives such a field. Prints the cost grid and the fitted minimum.

    PYTHONPATH=$PWD python docs/results/s32_oracle/map_offset_field.py --axis v
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.backend.map_offset import map_problem  # noqa: E402
from canopy.backend.stereo_ba import StereoEdges, _project, _robust_cost, bundle_adjust_points, edge_chi2  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.pipeline import run_sequential  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--axis", choices=["u", "v"], default="v")
    ap.add_argument("--path", default=None)
    ap.add_argument("--d0", type=float, nargs="+", default=[-0.1, -0.05, 0.0, 0.05, 0.1])
    ap.add_argument("--slope", type=float, nargs="+", default=[-0.4, -0.2, 0.0, 0.2, 0.4])
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    cfg = load_run_config("kitti")
    src = open_source("kitti", args.path or BUNDLED_DATA["kitti"])
    c = src.calibration
    tp, mp = cfg.tracking, cfg.mapping
    res = run_sequential(src, tp, mp, max_frames=None, map_update_lag=cfg.runtime.map_update_lag_frames)
    prob = map_problem(res.mapper.keyframes, res.mapper.landmarks, mp.pixel_sigma, tp.scale_factor,
                       mp.huber_stereo, mp.huber_mono)
    T, X, _ = bundle_adjust_points(prob.T_cw, prob.n_free, prob.X, prob.edges, c, 30, relative_tol=1e-7)
    e0 = prob.edges
    keep = edge_chi2(T, X, e0, c, 1e-6) <= np.where(e0.stereo, mp.chi2_stereo, mp.chi2_mono)
    e0 = e0.take(keep)
    coord = (e0.meas[:, 1] - c.cy) / c.height if args.axis == "v" else (e0.meas[:, 0] - c.cx) / c.width
    grid = np.zeros((len(args.d0), len(args.slope)))
    for i, d0 in enumerate(args.d0):
        for j, k in enumerate(args.slope):
            meas = e0.meas.copy()
            meas[:, 2] = np.where(e0.stereo, meas[:, 2] - (d0 + k * coord), 0.0)
            e = StereoEdges(e0.pose, e0.point, meas, e0.stereo, e0.sigma, e0.huber)
            Td, Xd, _ = bundle_adjust_points(T, prob.n_free, X, e, c, 30, relative_tol=1e-9)
            r, _, _, front = _project(Td, Xd, e, c)
            grid[i, j] = _robust_cost(r, front, e)[0]
    # quadratic surface fit: cost = a d0^2 + b k^2 + c d0 k + d d0 + e k + f
    D0, K = np.meshgrid(args.d0, args.slope, indexing="ij")
    A = np.stack([D0.ravel() ** 2, K.ravel() ** 2, D0.ravel() * K.ravel(), D0.ravel(), K.ravel(), np.ones(D0.size)], 1)
    coef = np.linalg.lstsq(A, grid.ravel(), rcond=None)[0]
    H = np.array([[2 * coef[0], coef[2]], [coef[2], 2 * coef[1]]])
    xmin = np.linalg.solve(H, -coef[3:5])
    out = {"axis": args.axis, "d0": args.d0, "slope": args.slope, "costs": grid.tolist(),
           "min_d0_rel": float(xmin[0]), "min_slope": float(xmin[1]), "config_offset": tp.disparity_offset_for(tp.extractor),
           "stereo_edges": int(e0.stereo.sum()), "keyframes": len(prob.keyframe_ids)}
    print(np.array2string(grid - grid.min(), precision=1))
    print(json.dumps({k: out[k] for k in ("axis", "min_d0_rel", "min_slope", "config_offset", "stereo_edges", "keyframes")}))
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
