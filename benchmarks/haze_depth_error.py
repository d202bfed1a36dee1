#!/usr/bin/env python
"""Painted-haze error of the tool's SGBM haze depths against the renderer's exact depth (s22-hazepaint).

On a generated preset (``mav0/depth0``: the renderer's exact left depth) every ``--step``-th frame is
hazed (``canopy.degrade.add_haze``, β ``--beta``, airlight 220) once from the exact depth (as
``tools/degrade_sequence.py --haze-depth rendered`` does) and once from each SGBM depth of the clean
rectified pair (``stereo``: ``depth_from_stereo``; ``stereo-sky``: ``depth_for_haze``), both cameras.
Reported, in grey levels, the painted image's error against the exact-depth haze:

* near depth edges: pixels within 8 px of an exact-depth discontinuity (ray length changes > 20 % in
  3x3), |error| mean; ``bg`` the background side of those (ray > 1.2x the 17x17 minimum), signed
  mean (negative: too little airlight, i.e. painted too near: SGBM's foreground fattening);
* away from edges, all pixels, and far pixels (exact ray > 40 m), the latter signed.

    PYTHONPATH=$PWD python benchmarks/haze_depth_error.py --path /work/cache/synthetic/day-loop-seed0-full \\
        [--step 100] [--beta 0.06] [--min-texture 1.5] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.degrade import (HAZE_MIN_TEXTURE, DegradeParams, add_haze, depth_for_haze,  # noqa: E402
                            depth_from_stereo, ray_length)
from canopy.sources import open_source  # noqa: E402
from tools.degrade_sequence import _depth_dir, _euroc_rectification, _rendered_rays  # noqa: E402

EDGE_RATIO = 1.2   # a depth edge: ray length changes by > 20 % within 3x3
NEAR_PX = 8.0      # "near an edge": within 8 px of one
FAR_M = 40.0       # s21's far band on KITTI (> 40 m)


def edge_regions(exact_ray: np.ndarray):
    """(near an exact-depth edge, background side of it) masks."""
    lr = np.log(exact_ray.astype(np.float32))
    rng3 = cv2.dilate(lr, np.ones((3, 3))) - cv2.erode(lr, np.ones((3, 3)))
    edge = (rng3 > np.log(EDGE_RATIO)).astype(np.uint8)
    near = cv2.distanceTransform(1 - edge, cv2.DIST_L2, 3) <= NEAR_PX
    bg = near & (lr > cv2.erode(lr, np.ones((17, 17))) + np.log(EDGE_RATIO))
    return near, bg


def haze_errors(image: np.ndarray, ray: np.ndarray, exact_ray: np.ndarray, beta: float, airlight: float = 220.0):
    """Per-region error (grey levels) of the haze painted from ``ray`` against the one from ``exact_ray``."""
    e = add_haze(image, ray, beta, airlight).astype(np.float64) - add_haze(image, exact_ray, beta, airlight)
    near, bg = edge_regions(exact_ray)
    far = exact_ray > FAR_M
    mean = lambda x: float(x.mean()) if x.size else float("nan")  # noqa: E731
    return {"near_abs": mean(np.abs(e[near])), "bg_signed": mean(e[bg]), "away_abs": mean(np.abs(e[~near])),
            "all_abs": mean(np.abs(e)), "far_abs": mean(np.abs(e[far])), "far_signed": mean(e[far])}


def depth_methods(min_texture: float):
    return {"stereo": lambda l, r, c, p, v: depth_from_stereo(l, r, c, p.max_depth, p.num_disparities,
                                                              p.block_size, view=v),
            "stereo-sky": lambda l, r, c, p, v: depth_for_haze(l, r, c, p.max_depth, p.num_disparities,
                                                               p.block_size, view=v, min_texture=min_texture)}


def measure(path: Path, step: int, beta: float, min_texture: float) -> dict:
    src = open_source("euroc", path)
    calib, params = src.calibration, DegradeParams(mode="haze", beta=beta)
    _, forward = _euroc_rectification(src)
    methods = depth_methods(min_texture)
    acc = {m: [] for m in methods}
    for i in range(0, len(src), step):
        fr = src.frame(i)
        exact = _rendered_rays(_depth_dir(src) / src.left_paths[i].name, forward[0], calib, params)
        for name, fn in methods.items():
            for v, img, ex in zip(("left", "right"), (fr.left, fr.right), exact):
                acc[name].append(haze_errors(img, ray_length(fn(fr.left, fr.right, calib, params, v), calib), ex, beta))
    return {m: {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]} for m, rows in acc.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--path", required=True, help="a generated preset (with mav0/depth0)")
    ap.add_argument("--step", type=int, default=100)
    ap.add_argument("--beta", type=float, default=0.06)
    ap.add_argument("--min-texture", type=float, default=HAZE_MIN_TEXTURE)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    res = measure(Path(args.path), args.step, args.beta, args.min_texture)
    for m, r in res.items():
        print(f"{m:10s} near-edge |e| {r['near_abs']:.2f}  bg-side {r['bg_signed']:+.2f}  away {r['away_abs']:.2f}  "
              f"all {r['all_abs']:.2f}  far |e| {r['far_abs']:.2f} ({r['far_signed']:+.2f})")
    if args.json:
        Path(args.json).write_text(json.dumps({"path": args.path, "step": args.step, "beta": args.beta,
                                               "min_texture": args.min_texture, "methods": res}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
