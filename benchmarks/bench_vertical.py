#!/usr/bin/env python
"""How good is the camera's "up" from vertical segments (``canopy.lines.vertical``) on the frames the tracker sees?

Per cell (a dataset's clean sequence or a degradation-grid cell, painted as ``bench_degrade_grid.py`` paints it and
kept in ``--cells-cache``), every frame's left image goes through the pipeline's enhancement (``auto``, as
``bench_enhance_diagnose.enhance_pair``: the tracker's image) and ``estimate_vertical`` twice: with a predicted up
(the true up turned by ``--prior-offset-deg`` about a random axis ⟂ it, seeded: the tracker's pose is about that
far off on the worst cells) and without one (the upright gate). Reported per cell and mode:

* share of frames with an estimate;
* on the generated presets (exact poses, world z up: up_cam = R_world_camᵀ e_z): the angle to the true up,
  p50 / p90, and its pitch (rotation about camera x) and roll (about camera z) parts, p50 of |·|;
* honesty of ``sigma_deg``: the share of frames with |pitch error| ≤ σ and ≤ 2σ (a Gaussian per axis: 68 % / 95 %),
  and the median of angle / σ (a 2-D Gaussian with σ per axis: 1.18);
* on KITTI / EuRoC (the GT world is the first camera's, not gravity's): consistency, the angles of
  R_world_cam_true · up_cam to their mean direction, p50 / p90 (a fixed world vertical gives zero spread);
* thread time per call (``time.thread_time``: detection + estimate, the predicted-up mode).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python benchmarks/bench_vertical.py \\
        --cells-cache /tmp/vertical-cache --out /tmp/vertical/bench_vertical.json \\
        [--cells day-loop:clean day-loop:g0.15-b0.06-high:1 kitti:g1-b0.06-low:0] [--set inlier_deg=0.7]
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_degrade_grid import PRESETS, cell_haze_depth, degraded_cell, sequence_path  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.degrade import grid_cells  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from benchmarks.bench_enhance_diagnose import enhance_pair  # noqa: E402
from canopy.lines.vertical import (VerticalEstimate, VerticalParams, detect_vertical_candidates,  # noqa: E402
                                   estimate_vertical_from_segments)
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402

# the brief's cells (s25 vertical): the target day-loop cell on two draws, its neighbours, the other presets' hazy
# cells, KITTI clean and hazy, EuRoC clean
DEFAULT_CELLS = ("day-loop:clean", "day-loop:g0.15-b0.06-high:0", "day-loop:g0.15-b0.06-high:1",
                 "day-loop:g0.15-b0-high:0", "day-loop:g1-b0.06-high:0", "dark-rows:g1-b0.06-high:0",
                 "haze-row:g1-b0.06-high:0", "kitti:clean", "kitti:g1-b0.06-low:0", "euroc:clean")
# the grid runner's frame counts (s25 brief: day-loop 300, dark-rows 150, haze-row 346, KITTI / EuRoC whole)
MAX_FRAMES = {"day-loop": 300, "dark-rows": 150, "haze-row": 346, "dusk-loop": 300, "kitti": None, "euroc": None}
E_Z = np.array([0.0, 0.0, 1.0])
# the world's up in the GT world frame: z on the generated presets (exact) and on EuRoC (the Vicon frame, levelled
# to gravity); KITTI's world is its first camera (x right, y down), about level: -y (the error against it then holds
# that camera's own tilt; the spread does not)
WORLD_UP = {"kitti": np.array([0.0, -1.0, 0.0])}


def parse_cell(spec: str):
    """"dataset:clean" or "dataset:gG-bB-noise:seed" -> (dataset, DegradeParams or None, label)."""
    parts = spec.split(":")
    if len(parts) == 2 and parts[1] == "clean":
        return parts[0], None, "clean"
    m = re.fullmatch(r"g([0-9.]+)-b([0-9.]+)-(\w+)", parts[1]) if len(parts) == 3 else None
    if m is None:
        raise SystemExit(f"bench_vertical: cell {spec!r} is not dataset:clean or dataset:gG-bB-noise:seed")
    cell = grid_cells((float(m.group(1)),), (float(m.group(2)),), (m.group(3),), seed=int(parts[2]))[0]
    return parts[0], cell, f"{cell.label}-seed{cell.seed}"


def pitch_roll_deg(up_cam: np.ndarray) -> tuple[float, float]:
    """Pitch (about camera x: up tipped towards +z) and roll (about camera z: up tipped towards +x), degrees."""
    x, y, z = up_cam
    return float(np.degrees(np.arctan2(z, -y))), float(np.degrees(np.arctan2(x, -y)))


def turned(v: np.ndarray, deg: float, rng: np.random.Generator) -> np.ndarray:
    """``v`` turned by ``deg`` towards a random direction ⟂ v."""
    a = rng.normal(size=3)
    a -= (a @ v) * v
    a /= np.linalg.norm(a)
    t = np.radians(deg)
    return np.cos(t) * v + np.sin(t) * a


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def summarise(est: list, truth_up: np.ndarray, R_wc: np.ndarray, times: list) -> dict:
    """One mode's numbers over the frames (``est``: VerticalEstimate or None per frame)."""
    got = np.array([e is not None for e in est])
    out = {"frames": len(est), "share": float(got.mean()) if len(est) else 0.0,
           "ms_p50": 1000 * float(np.median(times)) if times else None,
           "ms_p90": 1000 * float(np.percentile(times, 90)) if times else None}
    if not got.any():
        return out
    up = np.array([e.up_cam for e in est if e is not None])
    sig = np.array([e.sigma_deg for e in est if e is not None])
    out["n_inliers_p50"] = float(np.median([e.n_inliers for e in est if e is not None]))
    out["sigma_p50"] = float(np.median(sig))
    # against the world up (exact on the presets, nominal on KITTI / EuRoC)
    tu = truth_up[got]
    err = angle_deg(up, tu)
    pr_e = np.array([pitch_roll_deg(u) for u in up])
    pr_t = np.array([pitch_roll_deg(u) for u in tu])
    d = pr_e - pr_t
    out.update(err_p50=float(np.median(err)), err_p90=float(np.percentile(err, 90)),
               err_max=float(err.max()),
               pitch_p50=float(np.median(np.abs(d[:, 0]))), pitch_p90=float(np.percentile(np.abs(d[:, 0]), 90)),
               roll_p50=float(np.median(np.abs(d[:, 1]))), roll_p90=float(np.percentile(np.abs(d[:, 1]), 90)),
               pitch_bias=float(np.mean(d[:, 0])), roll_bias=float(np.mean(d[:, 1])),
               pitch_in_1sigma=float(np.mean(np.abs(d[:, 0]) <= sig)),
               pitch_in_2sigma=float(np.mean(np.abs(d[:, 0]) <= 2 * sig)),
               roll_in_1sigma=float(np.mean(np.abs(d[:, 1]) <= sig)),
               err_over_sigma_p50=float(np.median(err / sig)))
    # can a prior average it down? pitch errors' correlation between frames k apart, and the pitch error of the
    # mean over blocks of 30 consecutive frames (what a prior sees at the drift's low frequencies)
    pitch = np.full(len(est), np.nan)
    pitch[got] = d[:, 0]
    for lag in (1, 5, 20):
        a, b = pitch[:-lag], pitch[lag:]
        both = np.isfinite(a) & np.isfinite(b)
        out[f"pitch_corr_lag{lag}"] = float(np.corrcoef(a[both], b[both])[0, 1]) if both.sum() > 3 else None
    blocks = [np.nanmean(pitch[k:k + 30]) for k in range(0, len(pitch) - 29, 30) if np.isfinite(pitch[k:k + 30]).any()]
    out["pitch_block30_abs_p90"] = float(np.percentile(np.abs(blocks), 90)) if blocks else None
    # consistency: the up in the GT world frame should be one direction
    up_w = np.einsum("nij,nj->ni", R_wc[got], up)
    mean = up_w.mean(axis=0)
    mean /= np.linalg.norm(mean)
    spread = angle_deg(up_w, mean[None, :])
    out.update(spread_p50=float(np.median(spread)), spread_p90=float(np.percentile(spread, 90)),
               spread_max=float(spread.max()), world_up=mean.round(4).tolist(),
               spread_in_2sigma=float(np.mean(spread <= 2 * sig)))
    return out


def run_cell(spec: str, cache: Path, cells_cache: Path | None, tmp: Path, params: VerticalParams,
             prior_offset_deg: float, stride: int, max_frames_override, stereo: bool = False) -> dict:
    dataset, cell, label = parse_cell(spec)
    kind, clean_path = sequence_path(dataset, cache)
    max_frames = max_frames_override or MAX_FRAMES.get(dataset)
    path = clean_path
    if cell is not None:
        path, _ = degraded_cell(kind, dataset, clean_path, cell, max_frames, tmp, cells_cache,
                                cell_haze_depth("auto", dataset, kind, clean_path))
    config = "synthetic" if dataset in PRESETS else dataset
    enhancer = make_enhancer(replace(load_run_config(config).enhancement, method="auto"))
    src = open_source(kind, path, max_frames=max_frames)
    gt = open_source(kind, clean_path, max_frames=max_frames).ground_truth
    K = src.calibration.K
    frame_idx = (gt.meta or {}).get("frame_indices", range(len(gt.poses)))
    pose_of = dict(zip(frame_idx, gt.poses))  # frames without ground truth are skipped
    rng = np.random.default_rng(0)
    est_prior, est_free, est_stereo, times, truth, R_wc = [], [], [], [], [], []
    for i in range(0, len(src), stride):
        fr = src.frame(i)
        # the left image decides the treatment, the right gets the same (actors/enhancement.py)
        le, re, _ = enhance_pair(enhancer, fr.left, fr.right) if stereo else (*enhancer(fr.left)[:1], None, None)
        if i not in pose_of:
            continue
        R = pose_of[i][:3, :3]
        up_true = R.T @ WORLD_UP.get(dataset, E_Z)
        prior = turned(up_true, prior_offset_deg, rng)
        t0 = time.thread_time()
        segs = detect_vertical_candidates(le, params)
        e = estimate_vertical_from_segments(segs, K, prior, params, image=le)
        times.append(time.thread_time() - t0)
        est_prior.append(e)
        est_free.append(estimate_vertical_from_segments(segs, K, None, params, image=le))
        if stereo:  # the rectified right camera has the left's rotation: the same up, sampled apart
            est_stereo.append(fuse(e, estimate_vertical_from_segments(detect_vertical_candidates(re, params), K,
                                                                      prior, params, image=re)))
        truth.append(up_true)
        R_wc.append(R)
    truth_up = np.array(truth)
    R_wc = np.array(R_wc)
    out = {"cell": spec, "dataset": dataset, "label": label, "image": list(src.image_size),
           "prior": summarise(est_prior, truth_up, R_wc, times), "no_prior": summarise(est_free, truth_up, R_wc, [])}
    if stereo:
        out["stereo"] = summarise(est_stereo, truth_up, R_wc, [])
    return out


def fuse(a: VerticalEstimate | None, b: VerticalEstimate | None) -> VerticalEstimate | None:
    """Inverse-variance mean of two estimates of one up (either may be None); σ as if independent."""
    if a is None or b is None:
        return a if b is None else b
    wa, wb = a.sigma_deg ** -2, b.sigma_deg ** -2
    v = wa * a.up_cam + wb * b.up_cam
    return VerticalEstimate(v / np.linalg.norm(v), float((wa + wb) ** -0.5), a.n_inliers + b.n_inliers)


def fmt(v, nd=2):
    return "-" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))


def print_table(rows: list[dict]) -> None:
    head = (f"{'cell':<34} {'mode':<8} {'share':>5} {'p50':>5} {'p90':>5} {'pit50':>5} {'rol50':>5} {'pbias':>6} "
            f"{'sig50':>5} {'p≤1σ':>5} {'p≤2σ':>5} {'e/σ':>5} {'spr50':>5} {'spr90':>5} {'ninl':>4} {'ms50':>5} "
            f"{'r1':>5} {'r5':>5} {'r20':>5} {'blk30':>5}")
    print(head)
    for r in rows:
        for mode in ("prior", "no_prior", "stereo"):
            if mode not in r:
                continue
            s = r[mode]
            print(f"{r['cell']:<34} {mode:<8} {fmt(s['share'])} {fmt(s.get('err_p50'))} {fmt(s.get('err_p90'))} "
                  f"{fmt(s.get('pitch_p50'))} {fmt(s.get('roll_p50'))} {fmt(s.get('pitch_bias'), 3):>6} "
                  f"{fmt(s.get('sigma_p50'))} {fmt(s.get('pitch_in_1sigma'))} {fmt(s.get('pitch_in_2sigma'))} "
                  f"{fmt(s.get('err_over_sigma_p50'))} {fmt(s.get('spread_p50'))} {fmt(s.get('spread_p90'))} "
                  f"{fmt(s.get('n_inliers_p50'), 0):>4} {fmt(s.get('ms_p50'), 1):>5} "
                  f"{fmt(s.get('pitch_corr_lag1')):>5} "
                  f"{fmt(s.get('pitch_corr_lag5')):>5} {fmt(s.get('pitch_corr_lag20')):>5} "
                  f"{fmt(s.get('pitch_block30_abs_p90'), 3):>5}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", nargs="+", default=list(DEFAULT_CELLS))
    ap.add_argument("--cells-cache", default=None, metavar="DIR")
    ap.add_argument("--out", default=None, help="JSON file")
    ap.add_argument("--set", action="append", default=[], help="VerticalParams override name=value")
    ap.add_argument("--prior-offset-deg", type=float, default=1.0)
    ap.add_argument("--stride", type=int, default=1, help="every n-th frame")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--stereo", action="store_true", help="also the right image (enhanced as the left), fused with "
                    "the left's estimate by inverse variance: mode 'stereo' (predicted up)")
    args = ap.parse_args(argv)
    params = VerticalParams(**{k: parse_value(v) for k, v in (s.split("=", 1) for s in args.set)})
    cache = Path(os.environ.get("CANOPY_CACHE_DIR", ROOT / "cache"))
    cells_cache = Path(args.cells_cache) if args.cells_cache else None
    rows = []
    with tempfile.TemporaryDirectory(prefix="canopy_vertical_") as tmp:
        for spec in args.cells:
            start = time.time()
            rows.append(run_cell(spec, cache, cells_cache, Path(tmp), params, args.prior_offset_deg, args.stride,
                                 args.max_frames, args.stereo))
            print(f"  [{time.time() - start:5.0f} s] {spec}", file=sys.stderr, flush=True)
    print_table(rows)
    if args.out:
        write_json(Path(args.out), {"benchmark": "bench_vertical", "params": {k: v for k, v in vars(params).items()
                                                                            if k != "line_params"},
                                    "prior_offset_deg": args.prior_offset_deg, "stride": args.stride, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
