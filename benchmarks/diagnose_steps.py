#!/usr/bin/env python
"""Which frames take a bad step, and where does the step go wrong? (issue 9, KITTI's swinging cells)

Runs the tracker and local mapper in process on degraded copies of a sequence (the loop of
``bench_enhance_diagnose.run``: the actors' enhancement, FAST rule and lockstep map updates) and
records, per frame, the tracker's own step (its pose against its previous output, before local BA
moves the keyframes) against the ground-truth step, at three points of ``Tracker._track_frame``:

* the constant-velocity prediction T_last V (``pred``),
* EPnP RANSAC's pose (``ransac``; ``from_pred``: the motion check replaced it by the prediction),
* the final motion-only refinement (``final``),

each as the error of the camera centre's step (m) and its component along the optical axis of
the previous camera (``z``). For the final refinement: its inliers' depth (median, 10-90 %
spread), how many lie beyond 40 baselines, their octaves (mean), and the pose covariance's
standard deviation along the optical axis (``sd_z``: the inverse Fisher information's
translation block is the camera centre's covariance in the camera frame, to first order) and the
final pose's departure from the prediction in those sigmas (``k_z``).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python benchmarks/diagnose_steps.py \\
        --cells-cache /tmp/stepcheck-cache --gains 1 0.15 0.06 --betas 0 0.06 --noise low high --seeds 0 1 2 \\
        [--min-err 0.1] [--set tracking.name=value ...] [--out steps.json]
    python benchmarks/diagnose_steps.py --compare base.json on.json   # ATE per cell and draw, side by side
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_degrade_grid import degraded_cell, cell_haze_depth  # noqa: E402
from bench_enhance_diagnose import TrajectoryRecorder, actor_fast, enhance_pair  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.degrade import grid_cells  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv, transform  # noqa: E402
from canopy.frontend.track_health import motion_deviation  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402


class _Probe:
    """Records the RANSAC pose and the refinements of the frame being tracked (wraps the tracker's
    ``_ransac`` / ``_start_from_prediction`` / ``_refine``; their results are returned unchanged)."""

    def __init__(self, tracker: Tracker):
        self.reset()
        ransac, start, refine = tracker._ransac, tracker._start_from_prediction, tracker._refine

        def _ransac(*a, **k):
            out = ransac(*a, **k)
            self.ransac = out[0]
            return out

        def _start(*a, **k):
            out = start(*a, **k)
            self.from_pred = self.from_pred or out[2]
            return out

        def _refine(T_cw, X, r, feats, stereo, *a, **k):
            est = refine(T_cw, X, r, feats, stereo, *a, **k)
            self.refines.append((X, r, feats.octave[r], est))
            return est

        tracker._ransac, tracker._start_from_prediction, tracker._refine = _ransac, _start, _refine

    def reset(self):
        self.ransac, self.from_pred, self.refines, self.step = None, False, [], ""


def _probe_step_check(probes: dict):
    """Record what ``step_check.recheck_step`` did on the frame (``step``: "" not asked, "kept" the
    first solution, "replaced" by the solve from the prediction)."""
    import canopy.frontend.tracker as tracker_module
    from canopy.frontend.step_check import recheck_step, step_departs

    def _recheck(tracker, first, T_pred_cw, *a, **k):
        out = recheck_step(tracker, first, T_pred_cw, *a, **k)
        if first[0] is not None and step_departs(first[0].T_cam_world, T_pred_cw, tracker.params.step_max_deviation_m):
            probes[id(tracker)].step = "kept" if out is first else "replaced"
        return out

    tracker_module.recheck_step = _recheck


_PROBES: dict = {}
_probe_step_check(_PROBES)


def _step_error(T_prev_wc, T_wc, dg):
    """(|error| m, error along the previous camera's optical axis m) of the step T_prev -> T."""
    if T_wc is None:
        return np.nan, np.nan
    de = se3_inv(T_prev_wc) @ T_wc
    e = de[:3, 3] - dg[:3, 3]
    return float(np.linalg.norm(e)), float(e[2])


def run_cell(path: Path, clean_path, dataset: str, track_sets: dict) -> tuple[dict, list[dict]]:
    cfg = load_run_config(dataset)
    tp = replace(cfg.tracking, **track_sets)
    src, clean = open_source(dataset, path), open_source(dataset, clean_path)
    enh = replace(cfg.enhancement, method="auto")  # the grid's default column
    enhancer = make_enhancer(enh)
    tracker = Tracker(src.calibration, tp)
    probe = _Probe(tracker)
    _PROBES[id(tracker)] = probe
    mapper = LocalMapper(src.calibration, cfg.mapping)
    schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
    gt = clean.ground_truth.poses
    far = 40.0 * src.calibration.baseline
    rows, recorder = [], TrajectoryRecorder()
    T_prev = None
    for i in range(len(src)):
        fr = src.frame(i)
        for update in schedule.take_due(fr.index):
            tracker.apply_map_update(update)
        le, re, info = enhance_pair(enhancer, fr.left, fr.right)
        kw = actor_fast(enh, info, le, tp.n_features)
        T_pred_wc = tracker._T_last @ tracker._velocity
        probe.reset()
        res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re), **kw, sensor_sigma=info["noise_sigma"])
        row = {"i": i, "status": res.status, "inl": int(res.n_inliers), "matches": int(res.n_matches),
               "from_pred": probe.from_pred, "step": probe.step}
        if T_prev is not None and i > 0 and probe.refines:
            dg = se3_inv(gt[i - 1]) @ gt[i]
            row["gt_step"] = float(np.linalg.norm(dg[:3, 3]))
            row["err"], row["err_z"] = _step_error(T_prev, res.T_world_cam, dg)
            row["pred_err"], _ = _step_error(T_prev, T_pred_wc, dg)
            row["ransac_err"], row["ransac_err_z"] = _step_error(
                T_prev, None if probe.ransac is None else se3_inv(probe.ransac), dg)
            if probe.ransac is not None:  # what the motion check (track_health.ransac_departs) sees
                row["ransac_dev_m"], row["ransac_dev_deg"] = motion_deviation(probe.ransac, se3_inv(T_pred_wc))
            X, r, octv, est = probe.refines[-1]
            inl = est.inliers
            z = transform(est.T_cam_world, X[inl])[:, 2]
            if len(z):
                row.update(z_med=float(np.median(z)), z10=float(np.percentile(z, 10)),
                           z90=float(np.percentile(z, 90)), n_far=int((z > far).sum()),
                           oct_mean=float(octv[inl].mean()))
            try:
                cov = np.linalg.inv(est.information)
                row["sd_z"] = float(np.sqrt(max(cov[5, 5], 0.0)))
                # departure from the prediction along the optical axis, in the pose's own sigma
                d = (se3_inv(T_pred_wc) @ res.T_world_cam)[:3, 3]
                row["dev_pred"], row["k_z"] = float(np.linalg.norm(d)), float(d[2] / row["sd_z"])
            except np.linalg.LinAlgError:
                pass
        recorder.add(res, fr.index, schedule, mapper)
        T_prev = res.T_world_cam.copy()
        rows.append(row)
    est, tracked = recorder.trajectory(mapper)
    out = {"tracked": float(tracked.mean())}
    if tracked.sum() >= 3:
        out["ate"] = ape(est[tracked], gt[: len(est)][tracked], "se3")["rmse"]
    return out, rows


def _fmt(row: dict) -> str:
    keys = ["i", "status", "from_pred", "step", "inl", "matches", "gt_step", "err", "err_z", "pred_err", "ransac_err",
            "ransac_err_z", "ransac_dev_m", "ransac_dev_deg", "dev_pred", "sd_z", "k_z", "z_med", "z10", "z90", "n_far", "oct_mean"]
    return " ".join(f"{k}={row[k]:.3f}" if isinstance(row.get(k), float) else f"{k}={row.get(k)}"
                    for k in keys if k in row)


def compare(paths: list[str]) -> None:
    """Per cell, the ATE (mm) of every draw in each ``--out`` file, the median, and the bad steps."""
    runs = [json.loads(Path(f).read_text()) for f in paths]
    cells = sorted({name.rsplit("-seed", 1)[0] for run in runs for name in run})
    for cell in cells:
        cols = []
        for run in runs:
            draws = sorted((int(n.rsplit("-seed", 1)[1]), v) for n, v in run.items() if n.rsplit("-seed", 1)[0] == cell)
            ates = [v["summary"].get("ate", np.nan) * 1e3 for _, v in draws]
            tracked = [v["summary"]["tracked"] for _, v in draws]
            bad = [sum(r.get("err", 0.0) > 0.1 for r in v["rows"]) for _, v in draws]
            fired = [sum(r.get("step") == "replaced" for r in v["rows"]) for _, v in draws]
            lost = "" if min(tracked, default=1.0) == 1.0 else " tracked " + "/".join(f"{t:.2f}" for t in tracked)
            cols.append(" / ".join(f"{a:.1f}" for a in ates) + f" (med {np.median(ates):.1f}; >0.1 m steps "
                        + "/".join(map(str, bad)) + "; replaced " + "/".join(map(str, fired)) + lost + ")")
        print(f"{cell:18s} | " + " | ".join(cols))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    if len(sys.argv) > 1 and sys.argv[1] == "--compare":  # --compare A.json B.json ...
        compare(sys.argv[2:])
        return 0
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--cells-cache", required=True)
    ap.add_argument("--gains", type=float, nargs="+", default=[1.0])
    ap.add_argument("--betas", type=float, nargs="+", default=[0.06])
    ap.add_argument("--noise", nargs="+", default=["low"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--min-err", type=float, default=0.1, help="print frames whose step error exceeds this (m)")
    ap.add_argument("--set", action="append", default=[], help="tracking.name=value")
    ap.add_argument("--out", default=None, help="write every row as JSON here")
    args = ap.parse_args()
    trk = {k.removeprefix("tracking."): parse_value(v) for k, v in (s.split("=", 1) for s in args.set)}
    clean = Path(BUNDLED_DATA[args.dataset])
    allrows = {}
    for seed in args.seeds:
        for cell in grid_cells(args.gains, args.betas, args.noise, seed=seed):
            hd = cell_haze_depth("stereo", args.dataset, args.dataset, clean)
            path, _ = degraded_cell(args.dataset, args.dataset, clean, cell, None, Path(args.cells_cache),
                                    Path(args.cells_cache), hd)
            out, rows = run_cell(path, clean, args.dataset, trk)
            errs = [r["err"] for r in rows if np.isfinite(r.get("err", np.nan))]
            name = f"{cell.label}-seed{seed}"
            print(f"== {name}: tracked {out['tracked']:.3f} ATE {out.get('ate', np.nan) * 1e3:.1f} mm, "
                  f"step error median {np.median(errs) * 1e3:.1f} mm max {np.max(errs) * 1e3:.1f} mm", flush=True)
            for r in rows:
                if r.get("err", 0.0) > args.min_err or r.get("step"):
                    print("   ", _fmt(r), flush=True)
            allrows[name] = {"summary": out, "rows": rows}
    if args.out:
        Path(args.out).write_text(json.dumps(allrows, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
