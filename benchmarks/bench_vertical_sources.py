#!/usr/bin/env python
"""Where does the error of ``canopy.lines.vertical`` come from on a generated cell? (s25 vertical, item 4)

Per frame of a generated cell (exact up), with the estimator's own candidates (prior gate, sub-pixel refit):

* ``est``: the estimator's up (predicted up: truth turned by 1 deg, as ``bench_vertical.py``);
* ``oracle``: the same weighted eigenvector over the candidates that truly are vertical (|asin(n·up_true)| below
  ``--oracle-deg``; a tight one selects on the noise too and flatters the oracle): what is left is the segments'
  own precision (noise, blur, refit);
* the estimator's inliers that are not vertical (|asin(n·up_true)| > 2x the inlier threshold): how many, where
  (image row of the midpoint: top third / middle / bottom third) and whether they point at the rows' vanishing
  direction (world x, the driving direction: |n·d_row| < sin(2 deg) — the rows' converging edges);
* the true verticals' residual spread by length (short < 40 px, long ≥ 40 px; MAD·1.48, degrees).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python benchmarks/bench_vertical_sources.py \\
        --cells-cache /tmp/vertical-cache --cells day-loop:clean day-loop:g0.15-b0.06-high:0
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_degrade_grid import PRESETS, cell_haze_depth, degraded_cell, sequence_path  # noqa: E402
from benchmarks.bench_vertical import E_Z, MAX_FRAMES, angle_deg, parse_cell, turned  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.lines.features import segment_lengths  # noqa: E402
from canopy.lines.vertical import (VerticalParams, detect_vertical_candidates,  # noqa: E402
                                   estimate_vertical_from_segments, interpretation_normals,
                                   refine_segments_subpixel)
from canopy.sources import open_source  # noqa: E402


def eig_up(n: np.ndarray, w: np.ndarray, ref: np.ndarray) -> np.ndarray | None:
    if len(n) < 3:
        return None
    v = np.linalg.eigh((n * w[:, None]).T @ n)[1][:, 0]
    return v if v @ ref > 0 else -v


def run_cell(spec: str, cache: Path, cells_cache: Path, tmp: Path, p: VerticalParams, oracle_deg: float) -> dict:
    dataset, cell, _ = parse_cell(spec)
    if dataset not in PRESETS:
        raise SystemExit("bench_vertical_sources: generated presets only (exact up)")
    kind, clean_path = sequence_path(dataset, cache)
    max_frames = MAX_FRAMES[dataset]
    path = clean_path
    if cell is not None:
        path, _ = degraded_cell(kind, dataset, clean_path, cell, max_frames, tmp, cells_cache,
                                cell_haze_depth("auto", dataset, kind, clean_path))
    enhancer = make_enhancer(replace(load_run_config("synthetic").enhancement, method="auto"))
    src = open_source(kind, path, max_frames=max_frames)
    poses = open_source(kind, clean_path, max_frames=max_frames).ground_truth.poses
    K = src.calibration.K
    h = src.calibration.height
    rng = np.random.default_rng(0)
    sin_in = np.sin(np.radians(p.inlier_deg))
    err_est, err_orc, n_in, n_false, false_where, false_rows = [], [], [], [], np.zeros(3), 0
    res_short, res_long = [], []
    for i in range(len(src)):
        le, _ = enhancer(src.frame(i).left)
        R = poses[i][:3, :3]
        up = R.T @ E_Z
        d_row = R.T @ np.array([1.0, 0.0, 0.0])
        prior = turned(up, 1.0, rng)
        segs = detect_vertical_candidates(le, p)
        e = estimate_vertical_from_segments(segs, K, prior, p, image=le)
        n = interpretation_normals(segs, K)
        cand = np.abs(n @ prior) < np.sin(np.radians(p.max_prior_deg))
        s_c = refine_segments_subpixel(le, segs[cand], p.subpixel_samples, p.subpixel_reach_px)
        n_c, w_c = interpretation_normals(s_c, K), segment_lengths(s_c)
        r_true = np.degrees(np.arcsin(n_c @ up))
        true_v = np.abs(r_true) < oracle_deg
        res_short += r_true[true_v & (w_c < 40)].tolist()
        res_long += r_true[true_v & (w_c >= 40)].tolist()
        v_orc = eig_up(n_c[true_v], w_c[true_v], up)
        if v_orc is not None:
            err_orc.append(float(angle_deg(v_orc, up)))
        if e is None:
            continue
        err_est.append(float(angle_deg(e.up_cam, up)))
        v = e.up_cam
        inl = np.abs(n_c @ v) < sin_in
        bad = inl & (np.abs(r_true) > 2 * p.inlier_deg)
        n_in.append(int(inl.sum()))
        n_false.append(int(bad.sum()))
        mid_y = 0.5 * (s_c[bad, 1] + s_c[bad, 3])
        false_where += np.histogram(mid_y, bins=[0, h / 3, 2 * h / 3, h])[0]
        false_rows += int((np.abs(n_c[bad] @ d_row) < np.sin(np.radians(2.0))).sum())

    def mad(x):
        x = np.asarray(x)
        return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else None

    return {"cell": spec, "frames": len(src), "est_p50": float(np.median(err_est)),
            "est_p90": float(np.percentile(err_est, 90)), "oracle_p50": float(np.median(err_orc)),
            "oracle_p90": float(np.percentile(err_orc, 90)), "inliers_p50": float(np.median(n_in)),
            "false_inliers_per_frame": float(np.mean(n_false)),
            "frames_with_false_inlier": float(np.mean(np.array(n_false) > 0)),
            "false_top_mid_bottom": (false_where / max(false_where.sum(), 1)).round(2).tolist(),
            "false_towards_rows": false_rows / max(sum(n_false), 1),
            "true_residual_sd_short": mad(res_short), "true_residual_sd_long": mad(res_long),
            "true_short_long_counts": [len(res_short), len(res_long)]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", nargs="+", default=["day-loop:clean", "day-loop:g0.15-b0.06-high:0",
                                                   "day-loop:g0.15-b0.06-high:1"])
    ap.add_argument("--cells-cache", required=True)
    ap.add_argument("--oracle-deg", type=float, default=1.5, help="|asin(n·up_true)| of a true vertical")
    ap.add_argument("--set", action="append", default=[], help="VerticalParams override name=value")
    args = ap.parse_args(argv)
    p = VerticalParams(**{k: parse_value(v) for k, v in (s.split("=", 1) for s in args.set)})
    cache = Path(os.environ.get("CANOPY_CACHE_DIR", ROOT / "cache"))
    with tempfile.TemporaryDirectory(prefix="canopy_vsrc_") as tmp:
        for spec in args.cells:
            r = run_cell(spec, cache, Path(args.cells_cache), Path(tmp), p, args.oracle_deg)
            print(" ".join(f"{k}={round(v, 3) if isinstance(v, float) else v}" for k, v in r.items()), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
