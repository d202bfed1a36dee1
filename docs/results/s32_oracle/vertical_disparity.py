#!/usr/bin/env python
"""s32: the rectified pair's row misalignment from the images alone. For every stereo match of the tracker's own
matcher (octave 0 keypoints, bundled KITTI 06 or a --path), the right patch's row offset by SAD over +-2 rows at
the matched column (11x11 window, parabola vertex). A relative roll theta of the rectified cameras shows as a row
offset growing with the column, v_r - v_l = theta (u - cx), and a disparity error theta (v - cy); a pitch residual
as a constant row offset. Fits v_r - v_l = a + b (u - cx) + c (v - cy) (least squares, 2.5 px-clipped) and prints
the slope b (theta, rad) and what it implies for the disparity over the image height (KV = -theta * H).

    PYTHONPATH=$PWD python docs/results/s32_oracle/vertical_disparity.py [--dataset kitti --path FOLDER]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.cell_extractor import make_extractor  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402


def row_offsets(left, right, u, v, ur, w=5, search=2):
    """Row offset of the right patch at column round(ur) against the left patch at (u, v), sub-pixel."""
    h, W = left.shape
    ui, vi, uri = np.rint(u).astype(int), np.rint(v).astype(int), np.rint(ur).astype(int)
    ok = (vi - w - search >= 0) & (vi + w + search < h) & (ui - w >= 0) & (ui + w < W) & (uri - w >= 0) & (uri + w < W)
    ui, vi, uri = ui[ok], vi[ok], uri[ok]
    L = left.astype(np.int32)
    R = right.astype(np.int32)
    offs = np.arange(-w, w + 1)
    pl = L[vi[:, None, None] + offs[None, :, None], ui[:, None, None] + offs[None, None, :]]
    pl = pl - pl.mean(axis=(1, 2), keepdims=True)
    costs = []
    for s in range(-search, search + 1):
        pr = R[vi[:, None, None] + s + offs[None, :, None], uri[:, None, None] + offs[None, None, :]]
        pr = pr - pr.mean(axis=(1, 2), keepdims=True)
        costs.append(np.abs(pr - pl).sum(axis=(1, 2)))
    C = np.stack(costs, 1).astype(float)
    b = np.argmin(C, 1)
    inner = (b > 0) & (b < 2 * search)
    i = np.arange(len(C))
    bc = np.clip(b, 1, 2 * search - 1)
    d1, d2, d3 = C[i, bc - 1], C[i, bc], C[i, bc + 1]
    den = 2 * (d1 + d3 - 2 * d2)
    delta = np.where(den > 0, (d1 - d3) / np.where(den > 0, den, 1), 0)
    off = (bc - search) + delta
    return np.flatnonzero(ok)[inner], off[inner]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--path", default=None)
    ap.add_argument("--step", type=int, default=1)
    args = ap.parse_args()
    cfg = load_run_config(args.dataset)
    tp = cfg.tracking
    src = open_source(args.dataset, args.path or BUNDLED_DATA[args.dataset])
    c = src.calibration
    exl, exr = make_extractor(tp), make_extractor(tp)
    rows = []
    for i in range(0, len(src), args.step):
        f = src.frame(i)
        fl, fr = exl.extract(f.left), exr.extract(f.right)
        st = match_stereo(fl, fr, f.left, f.right, c, tp)
        ok = np.flatnonzero(st.valid & (fl.octave == 0))
        idx, off = row_offsets(f.left, f.right, fl.uv[ok, 0], fl.uv[ok, 1], st.u_right[ok])
        q = ok[idx]
        rows.append(np.stack([fl.uv[q, 0] - c.cx, fl.uv[q, 1] - c.cy, off], 1))
    R = np.concatenate(rows)
    keep = np.abs(R[:, 2]) < 1.5
    for _ in range(3):
        A = np.stack([np.ones(keep.sum()), R[keep, 0], R[keep, 1]], 1)
        coef, *_ = np.linalg.lstsq(A, R[keep, 2], rcond=None)
        res = R[:, 2] - np.stack([np.ones(len(R)), R[:, 0], R[:, 1]], 1) @ coef
        s = 1.4826 * np.median(np.abs(res[keep]))
        keep = np.abs(res) < 2.5 * s
    A = np.stack([np.ones(keep.sum()), R[keep, 0], R[keep, 1]], 1)
    cov = np.linalg.inv(A.T @ A) * s ** 2
    se = np.sqrt(np.diag(cov))
    bins = np.linspace(-c.cx, c.width - c.cx, 7)
    prof = [float(np.median(R[keep & (R[:, 0] >= a) & (R[:, 0] < b), 2])) for a, b in zip(bins[:-1], bins[1:])]
    out = {"n": int(keep.sum()), "a_px": coef[0], "b_theta_rad": coef[1], "b_se": se[1], "c": coef[2], "c_se": se[2],
           "KV_px_per_height": -coef[1] * c.height, "row_offset_by_column_sixth": prof}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
