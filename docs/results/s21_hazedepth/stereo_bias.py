#!/usr/bin/env python
"""Signed stereo disparity error of the tracker's own stereo matches, by octave and depth band (s21).

Runs ``benchmarks/bench_enhance_diagnose.run`` (tracker + local mapper in process, the actors'
enhancement) on a cell and records every frame's stereo matches as the tracker made them
(``tracker_worker.frame_stereo`` wrapped). Reference disparity:

* generated presets (``mav0/depth0``): the exact one, bf / z of the rendered depth at the keypoint
  (kept only where the 5x5 depth around it varies < 3 %: no depth edge inside);
* KITTI: the clean pair's refined disparity of the same keypoint (``subpixel_refine`` on the clean
  pair from the hazy match's column) -- "the clean pair's disparity on the same keypoints".

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s21_hazedepth/stereo_bias.py \\
        --path /tmp/hazedepth-cache/dusk-loop-300-g0.3-b0.03-high-seed11-rendered \\
        --clean /work/cache/synthetic/dusk-loop-seed0-full --config synthetic --kind euroc --frames 300 \\
        [--set name=value ...] [--fit parabola|equiangular]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import canopy.frontend.tracker_worker as tw  # noqa: E402
from benchmarks.bench_enhance_diagnose import run  # noqa: E402
from canopy.config import parse_value  # noqa: E402
from canopy.frontend.stereo import subpixel_refine  # noqa: E402
from canopy.sources import open_source  # noqa: E402

RECORD: list = []


def wrap_frame_stereo():
    orig = tw.frame_stereo

    def frame_stereo(left, right, frame, calib, params, scale_factors, noise_sigma, pyramids=None, sensor_sigma=None):
        st = orig(left, right, frame, calib, params, scale_factors, noise_sigma, pyramids, sensor_sigma)
        RECORD.append((frame.index, left, st, calib, params))
        return st
    tw.frame_stereo = frame_stereo


def equiangular_minimum(sad: np.ndarray, L: int):
    """``parabola_minimum`` with the equiangular (V) fit instead of the parabola: the SAD (L1) cost is
    V-shaped around its minimum, and a parabola through it pulls the vertex towards the integer shift
    (pixel locking; Shimizu & Okutomi 2001, "Precise sub-pixel estimation on area-based matching")."""
    best = np.argmin(sad, axis=1)
    interior = (best > 0) & (best < 2 * L)
    idx = np.arange(len(sad))
    b = np.clip(best, 1, 2 * L - 1)
    d1, d2, d3 = sad[idx, b - 1], sad[idx, b], sad[idx, b + 1]
    denom = 2.0 * (np.maximum(d1, d3) - d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(denom > 0, (d1 - d3) / denom, 0.0)
    delta = np.where(interior, delta, 0.0)
    good = interior & (np.abs(delta) <= 1.0)
    return best, delta, sad[idx, best], good


def exact_disparity(depth_png: Path, uv: np.ndarray, bf: float) -> np.ndarray:
    z = cv2.imread(str(depth_png), cv2.IMREAD_UNCHANGED).astype(np.float64) / 1000.0
    h, w = z.shape
    zmax = cv2.dilate(z, np.ones((5, 5)))
    zlo = cv2.erode(z, np.ones((5, 5)))
    x = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
    zz, lo, hi = z[y, x], zlo[y, x], zmax[y, x]
    ok = (zz > 0) & (lo > 0) & (hi < 1.03 * lo)
    return np.where(ok, bf / np.maximum(zz, 1e-9), np.nan)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--path", required=True)
    ap.add_argument("--clean", required=True)
    ap.add_argument("--config", default="synthetic")
    ap.add_argument("--kind", default="euroc")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--method", default="auto")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--out", default=None)
    ap.add_argument("--ref", choices=("auto", "clean"), default="auto",
                    help="reference disparity: auto = the exact depth where the clean sequence has it, else the "
                         "clean pair's; clean = the clean pair's refined disparity at the same keypoints on a "
                         "preset too (KITTI's measure, no depth-edge exclusion; s22-hazepaint)")
    ap.add_argument("--fit", choices=("parabola", "equiangular"), default="parabola",
                    help="sub-pixel fit of the SAD minimum (equiangular: Shimizu & Okutomi's V fit for SAD)")
    args = ap.parse_args()
    if args.fit == "equiangular":
        import canopy.frontend.stereo as stereo_mod
        stereo_mod.parabola_minimum = equiangular_minimum
    sets = {}
    for s in args.set:
        k, v = s.split("=", 1)
        sets[k.split(".")[-1]] = parse_value(v)
    wrap_frame_stereo()
    out, rows = run(Path(args.path), Path(args.clean), args.config, {"method": args.method}, sets, args.frames,
                    stereo=False, kind=args.kind)
    print(json.dumps({k: out.get(k) for k in ("tracked", "ate", "ate_sim3", "scale")}))
    clean = open_source(args.kind, Path(args.clean), max_frames=args.frames)
    depth_dir = Path(args.clean) / "mav0" / "depth0" / "data"
    exact = depth_dir.is_dir() and args.ref == "auto"
    cams = sorted((Path(args.clean) / "mav0" / "cam0" / "data").glob("*.png")) if exact else None
    recs = []
    for idx, left, st, calib, params in RECORD:
        ok = np.flatnonzero(st.valid)
        if len(ok) == 0:
            continue
        uv = left.uv[ok].astype(np.float64)
        d_est = uv[:, 0] - st.u_right[ok]
        if exact:
            d_ref = exact_disparity(depth_dir / cams[idx].name, uv, calib.bf)
        else:
            c = clean.frame(idx)
            sf = params.scale_factor ** np.arange(params.n_levels)
            ur, _, good = subpixel_refine(c.left, c.right, uv, st.u_right[ok].astype(np.float64), left.octave[ok], sf,
                                          params.subpixel_window, params.subpixel_search, params.subpixel_normalise)
            d_ref = np.where(good, uv[:, 0] - (ur - params.disparity_offset_for(left.extractor)), np.nan)
        recs.append(np.column_stack([np.full(len(ok), idx), left.octave[ok], d_est, d_ref, calib.bf / d_est, uv]))
    A = np.concatenate(recs)
    fin = np.isfinite(A[:, 3]) & (A[:, 3] > 0)
    A = A[fin]
    err = A[:, 2] - A[:, 3]
    near = np.abs(err) <= 2.0
    z_true = calib.bf / A[:, 3]
    rel_z = A[:, 4] / z_true - 1.0
    print(f"matches scored {len(A)}; |err|<=2px {near.mean():.3f}; signed err mean(|e|<=2) {err[near].mean():+.4f} px "
          f"median {np.median(err):+.4f}; depth rel median {np.median(rel_z):+.4f} mean(|e|<=2) {rel_z[near].mean():+.4f}")
    bands = [0, 2, 4, 8, 16, 32, 1e9] if exact else [0, 5, 10, 20, 40, 1e9]
    print("by true depth band (m): n, frac|e|>2, signed err median / mean(|e|<=2) px, depth rel median")
    for a, b in zip(bands[:-1], bands[1:]):
        m = (z_true >= a) & (z_true < b)
        if m.sum() < 20:
            continue
        mn = m & near
        print(f"  [{a:4.0f},{b:4.0f}) n={m.sum():6d} bad={1 - near[m].mean():.3f} med={np.median(err[m]):+.4f} "
              f"mean={err[mn].mean():+.4f} relz_med={np.median(rel_z[m]):+.4f}")
    print("by octave: n, signed err median / mean(|e|<=2) px, |e| median, depth rel median")
    for o in range(int(A[:, 1].max()) + 1):
        m = A[:, 1] == o
        if m.sum() < 20:
            continue
        mn = m & near
        print(f"  o{o} n={m.sum():6d} med={np.median(err[m]):+.4f} mean={err[mn].mean():+.4f} "
              f"abs_med={np.median(np.abs(err[m])):.4f} relz_med={np.median(rel_z[m]):+.4f}")
    frac = A[:, 2] - np.floor(A[:, 2])
    hist = np.histogram(frac, bins=10, range=(0, 1))[0]
    print("fractional part of the estimated disparity (pixel locking shows as peaks at 0 / 1):", hist.tolist())
    if args.out:  # columns: frame, octave, disparity, reference disparity, depth, u, v
        np.save(args.out, A)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
