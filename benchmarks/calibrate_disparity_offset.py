#!/usr/bin/env python
"""Measure a stereo rig's constant disparity offset from its images alone (no ground truth).

For consecutive frame pairs: ORB + stereo matches in both frames, descriptor matches between
the left images, EPnP RANSAC on the stereo points for inliers and a first relative pose, then
``canopy.frontend.disparity_offset.estimate_disparity_offset`` (two-frame stereo BA with the
points, the pose and the offset free). Prints the median over the pairs and its bootstrap
standard error, and writes JSON; the median goes to the config as ``tracking.disparity_offset_px``
(``tracking.disparity_offset_cells_px`` with ``--extractor cells``: the offset depends on the
extractor's keypoint localisation).

``--method map`` (s30) instead tracks and maps the sequence in process with the config (and its current
offset), then takes the whole map's bundle adjustment over a grid of extra offsets
(``canopy.backend.map_offset``): the offset printed is the config's plus the profile's minimum, with a
standard error from the profile's curvature. Each point is seen from several keyframes metres apart there,
so the map pins the offset more tightly than consecutive pairs do (KITTI 06 snippet, cells extractor:
+0.100 +- 0.013 px against the pairs' +0.151 +- 0.035; the generated day-loop, whose rig is exact, -0.047).

    PYTHONPATH=$PWD python benchmarks/calibrate_disparity_offset.py --dataset kitti
    PYTHONPATH=$PWD python benchmarks/calibrate_disparity_offset.py --dataset kitti --extractor cells \
        --out docs/results/disparity_offset_cells.json
    PYTHONPATH=$PWD python benchmarks/calibrate_disparity_offset.py --dataset euroc --path <mav folder> --config synthetic
    PYTHONPATH=$PWD python benchmarks/calibrate_disparity_offset.py --dataset kitti --method map \
        --out docs/results/disparity_offset_map_kitti.json
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

from canopy.backend.map_offset import map_offset_profile, map_problem  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.disparity_offset import estimate_disparity_offset  # noqa: E402
from canopy.frontend.cell_extractor import make_extractor  # noqa: E402
from canopy.frontend.geometry import pose_from_rvec  # noqa: E402
from canopy.frontend.matching import knn_match  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.pipeline import run_sequential  # noqa: E402
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


def map_estimate(src, cfg, n_frames: int, passes: int = 3) -> dict:
    """The offset from the whole map of an in-process run (module docstring). The map is built with the
    offset it is run at, and one profile moves only part of the way from there (KITTI: runs at 0 / 0.098 /
    0.2 px give 0.066 / 0.097 / 0.116), so the run is repeated at each estimate until the estimate moves by
    less than half its standard error (``passes`` runs at most)."""
    tp, mp = cfg.tracking, cfg.mapping
    base = tp.disparity_offset_for(tp.extractor)
    history = []
    for _ in range(max(1, passes)):
        res = run_sequential(src, tp, mp, max_frames=n_frames, map_update_lag=cfg.runtime.map_update_lag_frames)
        prob = map_problem(res.mapper.keyframes, res.mapper.landmarks, mp.pixel_sigma, tp.scale_factor,
                           mp.huber_stereo, mp.huber_mono)
        prof = map_offset_profile(prob, src.calibration, mp.chi2_stereo, mp.chi2_mono)
        history.append({"run_offset_px": base, "offset_px": base + prof.offset_px, "se_px": prof.se_px})
        if not np.isfinite(prof.se_px) or abs(prof.offset_px) < 0.5 * prof.se_px:
            break
        base = base + prof.offset_px
        tp = replace(tp, disparity_offset_px=base, disparity_offset_cells_px=base)
    last = history[-1]
    return {**last, "passes": history, "profile_deltas_px": prof.deltas.tolist(), "profile_costs": prof.costs.tolist(),
            "keyframes": len(prob.keyframe_ids), "edges": prof.n_edges, "stereo_edges": prof.n_stereo}


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
    ap.add_argument("--method", choices=("pairs", "map"), default="pairs",
                    help="pairs: the median of two-frame estimates; map: the profile of the whole map's bundle "
                         "adjustment after an in-process run with the config's offset")
    ap.add_argument("--passes", type=int, default=3, help="with --method map: runs at most, each at the last estimate")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "disparity_offset.json"))
    args = ap.parse_args()
    cfg = load_run_config(args.config or args.dataset)
    tp = cfg.tracking
    if args.extractor:
        tp = replace(tp, extractor=args.extractor)
    if args.normalise:
        tp = replace(tp, subpixel_normalise=args.normalise)
    src = open_source(args.dataset, args.path)
    if args.method == "map":
        try:
            out = map_estimate(src, replace(cfg, tracking=tp), min(len(src), args.max_frames), args.passes)
        except ValueError as exc:
            print(f"calibrate_disparity_offset: {args.path or args.dataset}: {exc}", file=sys.stderr)
            return 1
        if not np.isfinite(out["se_px"]):
            print(f"calibrate_disparity_offset: {args.path or args.dataset}: the map's cost falls all the way to the "
                  f"grid's edge ({out['offset_px']:+.3f} px): the offset is not observable from this run (the camera "
                  f"must travel several baselines past points at several depths)", file=sys.stderr)
            return 1
        print(f"{args.dataset} {args.path or '(bundled)'} ({tp.extractor}, map of {out['keyframes']} keyframes, "
              f"{out['stereo_edges']} stereo observations): disparity offset {out['offset_px']:+.3f} px "
              f"(se {out['se_px']:.3f}; last run at {out['run_offset_px']:+.3f}, {len(out['passes'])} runs)")
        write_json(args.out, {"dataset": args.dataset, "extractor": tp.extractor, "path": args.path,
                              "method": "map", **out})
        return 0
    tp = replace(tp, disparity_offset_px=0.0, disparity_offset_cells_px=0.0)
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
