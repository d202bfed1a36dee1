#!/usr/bin/env python
"""Measure a stereo rig's constant disparity offset from its images alone (no ground truth).

For consecutive frame pairs: ORB + stereo matches in both frames, descriptor matches between
the left images, EPnP RANSAC on the stereo points for inliers and a first relative pose, then
``canopy.frontend.disparity_offset.estimate_disparity_offset`` (two-frame stereo BA with the
points, the pose and the offset free). Prints the median over the pairs and its bootstrap
standard error, and writes JSON; the median goes to the config as ``tracking.disparity_offset_px``
(``tracking.disparity_offset_cells_px`` with ``--extractor cells``: the offset depends on the
extractor's keypoint localisation).

    PYTHONPATH=$PWD python benchmarks/calibrate_disparity_offset.py --dataset kitti
    PYTHONPATH=$PWD python benchmarks/calibrate_disparity_offset.py --dataset kitti --extractor cells \
        --out docs/results/disparity_offset_cells.json
    PYTHONPATH=$PWD python benchmarks/calibrate_disparity_offset.py --dataset euroc --path <mav folder> --config synthetic
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.disparity_offset import estimate_disparity_offset  # noqa: E402
from canopy.frontend.cell_extractor import make_extractor  # noqa: E402
from canopy.frontend.geometry import pose_from_rvec  # noqa: E402
from canopy.frontend.matching import knn_match  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402

MIN_PAIR_INLIERS = 50
TEMPORAL_MAX_HAMMING, TEMPORAL_RATIO = 50, 0.8
PNP_ERROR_PX = 2.0


def pair_estimates(src, tp, n_frames: int, step: int) -> np.ndarray:
    c = src.calibration
    ex_l, ex_r = make_extractor(tp), make_extractor(tp)  # tracking.extractor: the offset depends on it
    frames = []
    for i in range(0, n_frames, step):
        f = src.frame(i)
        left, right = ex_l.extract(f.left), ex_r.extract(f.right)
        frames.append((left, match_stereo(left, right, f.left, f.right, c, tp)))
    out = []
    for (L1, s1), (L2, s2) in zip(frames[:-1], frames[1:]):
        q, r, _ = knn_match(L1.descriptors, L2.descriptors, TEMPORAL_MAX_HAMMING, TEMPORAL_RATIO)
        ok = s1.valid[q] & s2.valid[r]
        q, r = q[ok], r[ok]
        if len(q) < MIN_PAIR_INLIERS:
            continue
        uv1, uv2 = L1.uv[q].astype(float), L2.uv[r].astype(float)
        d1, d2 = uv1[:, 0] - s1.u_right[q], uv2[:, 0] - s2.u_right[r]
        z = c.bf / d1
        X1 = np.column_stack([(uv1[:, 0] - c.cx) * z / c.fx, (uv1[:, 1] - c.cy) * z / c.fy, z])
        found, rvec, tvec, inl = cv2.solvePnPRansac(X1.reshape(-1, 1, 3), uv2.reshape(-1, 1, 2), c.K, None,
                                                    reprojectionError=PNP_ERROR_PX, iterationsCount=200,
                                                    flags=cv2.SOLVEPNP_EPNP)
        if not found or inl is None or len(inl) < MIN_PAIR_INLIERS:
            continue
        i = inl.ravel()
        delta, sd, _ = estimate_disparity_offset(uv1[i], d1[i], tp.scale_factor ** L1.octave[q][i], uv2[i], d2[i],
                                                 tp.scale_factor ** L2.octave[r][i], pose_from_rvec(rvec, tvec), c)
        if np.isfinite(sd):
            out.append((delta, sd))
    return np.asarray(out).reshape(-1, 2)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="kitti", help="euroc | kitti | folder")
    ap.add_argument("--path", default=None, help="dataset folder (default: the bundled copy)")
    ap.add_argument("--config", default=None, help="config whose tracking section to use (default: the dataset's)")
    ap.add_argument("--max-frames", type=int, default=300)
    ap.add_argument("--step", type=int, default=1, help="use every step-th frame (moving sequences at high rate)")
    ap.add_argument("--extractor", choices=("opencv", "cells"), default=None,
                    help="keypoint extractor (default: the config's tracking.extractor); the cells extractor's "
                         "offset goes to tracking.disparity_offset_cells_px")
    ap.add_argument("--normalise", choices=("centre", "mean"), default=None,
                    help="sub-pixel SAD normalisation (default: the config's tracking.subpixel_normalise): the "
                         "offset depends on the refinement as on the extractor; 'mean' is the zero-mean SAD of "
                         "the hazy frames (canopy.frontend.stereo)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "disparity_offset.json"))
    args = ap.parse_args()
    tp = load_run_config(args.config or args.dataset).tracking
    if args.extractor:
        tp = replace(tp, extractor=args.extractor)
    if args.normalise:
        tp = replace(tp, subpixel_normalise=args.normalise)
    tp = replace(tp, disparity_offset_px=0.0, disparity_offset_cells_px=0.0)
    src = open_source(args.dataset, args.path)
    est = pair_estimates(src, tp, min(len(src), args.max_frames), args.step)
    if len(est) == 0:
        print("no usable frame pairs (the camera must move)")
        return 1
    med = float(np.median(est[:, 0]))
    rng = np.random.default_rng(0)
    boot = [np.median(rng.choice(est[:, 0], len(est))) for _ in range(500)]
    se = float(np.std(boot))
    print(f"{args.dataset} {args.path or '(bundled)'} ({tp.extractor}): {len(est)} pairs, disparity offset median {med:+.3f} px "
          f"(bootstrap se {se:.3f}; per-pair sd median {np.median(est[:, 1]):.2f} px)")
    write_json(args.out, {"dataset": args.dataset, "extractor": tp.extractor, "path": args.path, "pairs": int(len(est)),
                          "offset_px_median": med, "bootstrap_se_px": se,
                          "per_pair_sd_median_px": float(np.median(est[:, 1])), "step": args.step})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
