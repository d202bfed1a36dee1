"""Points only vs points + lines through the lockstep pipeline (issue 4, items 4-5).

Speed and accuracy, per dataset snippet (EuRoC V1_01 micro slice 752x480, KITTI 06 snippet
1226x370):

* ``run_sequential`` with ``use_lines`` off and on, ``--repeats`` times each, interleaved (the
  machine may be shared: every timing is the median over the repeats of the per-run p50,
  and "lines add" is the median of the per-repeat differences, each pair run back to back):
  frames tracked, lost frames, keyframes, ATE (SE(3)-aligned RMSE against ground truth),
  tracking total p50 / p95 (ms), the line stages (worker detection / LBD, which overlap ORB
  and stereo; the main-thread waits for them; temporal line matching), local-BA p50 per
  keyframe and map sizes. Runs are deterministic, so counts and ATE come from the first.
* BA on the same keyframes: the keyframes of a points + lines run are replayed into a
  points-only mapper and a points + lines mapper (``projection`` and ``custom`` factors),
  ``--repeats`` times interleaved; BA p50 per keyframe and the ratio to points only (issue
  target <= 1.5x). ``ratio_projection_equal_tol`` compares with points-only BA stopped by the
  same LM relative tolerance as the line BA (``MappingParams.line_ba_relative_error_tol``).

Robustness on low-texture / low-light input (points only vs points + lines: frames tracked,
first lost frame, keyframes, ATE over all frames with lost frames holding the last pose, ATE
over the tracked frames only):

* darkened snippets: every rectified frame through ``canopy.degrade.darken`` (gain
  ``--dark-gains``, shot + read noise seeded per seed, frame and camera; ``--dark-seeds``);
* generated orchard sequences (``canopy.synthetic``, "day-loop", 200 frames, seed 0) whose
  ground and crowns beyond x = 6 m are washed out (contrast 0.05) while the light fades to
  ``light_end`` (``--synthetic-light-ends``), cached in ``--synthetic-dir``.

    python benchmarks/bench_lines_slam.py [--out results/bench_lines_slam.json] [--repeats 3]
        [--skip-speed] [--skip-robustness]
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import canopy.backend.local_mapper as local_mapper  # noqa: E402
from canopy.backend import LocalMapper, MappingParams  # noqa: E402
from canopy.degrade import darken  # noqa: E402
from canopy.frontend import Tracker, TrackingParams  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import run_sequential  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

DATASETS = ("euroc", "kitti")
LINE_STAGES = ("lines_detect_worker", "lines_describe_worker", "lines_wait", "lines_right_wait",
               "lines_right_on_demand", "line_match")
LOST = "lost"
# generated low-texture sequence: washed-out ground and crowns beyond x = 6 m, fading light
SYNTHETIC = dict(preset="day-loop", n_frames=200, seed=0, low_texture=((6.0, 40.0),), low_texture_contrast=0.05,
                 light_start=1.0, light_ramp=(0.2, 0.6))


def _p(summary: dict, key: str, q: str = "p50") -> float | None:
    return round(summary[key][q], 2) if key in summary else None


def _ate(traj_poses: np.ndarray, gt_poses: np.ndarray, mask: np.ndarray | None = None) -> float | None:
    if mask is not None:
        if mask.sum() < 3:
            return None
        traj_poses, gt_poses = traj_poses[mask], gt_poses[mask]
    return round(float(ape(traj_poses, gt_poses, align="se3")["rmse"]), 4)


def run_mode(src, use_lines: bool) -> dict:
    res = run_sequential(src, TrackingParams(use_lines=use_lines), MappingParams(use_lines=use_lines))
    s = res.timing_summary()
    gt = src.ground_truth
    tracked = np.array([st != LOST for st in res.statuses])
    out = {"frames": res.n_frames, "tracked": int(tracked.sum()), "lost": res.n_lost,
           "first_lost": next((i for i, st in enumerate(res.statuses) if st == LOST), None),
           "keyframes": len(res.keyframe_indices),
           "ate_m": None if gt is None else _ate(res.trajectory.poses, gt.poses),
           "ate_tracked_m": None if gt is None else _ate(res.trajectory.poses, gt.poses, tracked),
           "tracking_p50_ms": _p(s, "tracking.total"), "tracking_p95_ms": _p(s, "tracking.total", "p95"),
           "ba_p50_ms": _p(s, "mapping.ba"), "map_points": int(len(res.map_points)),
           "map_lines": int(len(res.map_lines))}
    out.update({f"{k}_p50_ms": _p(s, f"tracking.{k}") for k in LINE_STAGES if f"tracking.{k}" in s})
    out.update({f"{k}_n": s[f"tracking.{k}"]["n"] for k in ("lines_right_wait", "lines_right_on_demand")
                if f"tracking.{k}" in s})
    return out


def speed_and_accuracy(src, repeats: int) -> dict:
    """Both modes ``repeats`` times, interleaved; timings: medians over the repeats."""
    runs = {"points": [], "points_lines": []}
    for _ in range(repeats):
        runs["points"].append(run_mode(src, False))
        runs["points_lines"].append(run_mode(src, True))
    entry = {}
    for mode, rs in runs.items():
        e = dict(rs[0])
        for k in e:
            if k.endswith("_ms") and e[k] is not None:
                e[k] = round(float(np.median([r[k] for r in rs if r.get(k) is not None])), 2)
        e["tracking_p50_ms_runs"] = [r["tracking_p50_ms"] for r in rs]
        entry[mode] = e
    added = [on["tracking_p50_ms"] - off["tracking_p50_ms"] for off, on in zip(runs["points"], runs["points_lines"])]
    entry["lines_add_tracking_p50_ms"] = round(float(np.median(added)), 2)
    entry["lines_add_tracking_p50_ms_runs"] = [round(a, 2) for a in added]
    return entry


def _lm_params_with_tol(tol: float):
    def make():
        q = gtsam.LevenbergMarquardtParams()
        q.setRelativeErrorTol(tol)
        return q
    return make


def ba_same_keyframes(src, repeats: int) -> dict:
    """Collect the keyframes of a points + lines run, replay them into the mappers."""
    calib = src.calibration
    tracker = Tracker(calib, TrackingParams(use_lines=True))
    mapper = LocalMapper(calib, MappingParams(use_lines=True))
    kfs = []
    for i in range(len(src)):
        res = tracker.track(src.frame(i))
        if res.is_keyframe and res.keyframe is not None:
            kfs.append(res.keyframe)
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
    line_tol = MappingParams().line_ba_relative_error_tol
    configs = (("points", MappingParams(), None), ("points_equal_tol", MappingParams(), line_tol),
               ("lines_projection", MappingParams(use_lines=True), None),
               ("lines_custom", MappingParams(use_lines=True, line_factor="custom"), None))
    times: dict[str, list[float]] = {name: [] for name, _, _ in configs}
    for rep in range(repeats):
        for name, params, tol in configs:
            if name == "lines_custom" and rep > 0:
                continue  # ~15-35x slower: one run is enough to place it
            m = LocalMapper(calib, params)
            if tol is not None:  # the points-only path has no tolerance knob: swap GTSAM's default here
                local_mapper.gtsam = _GtsamWithParams(_lm_params_with_tol(tol))
            try:
                ba = [m.insert_keyframe(kf).timings["ba"] for kf in kfs]
            finally:
                local_mapper.gtsam = gtsam
            times[name].append(float(np.median(ba)))
    out = {"keyframes": len(kfs), "repeats": repeats}
    for name, t in times.items():
        out[f"ba_p50_ms_{name}"] = round(float(np.median(t)), 2)
    base = out["ba_p50_ms_points"]
    out["ratio_projection"] = round(out["ba_p50_ms_lines_projection"] / base, 2)
    out["ratio_projection_runs"] = [round(b / a, 2) for a, b in zip(times["points"], times["lines_projection"])]
    out["ratio_projection_equal_tol"] = round(out["ba_p50_ms_lines_projection"] / out["ba_p50_ms_points_equal_tol"], 2)
    out["ratio_custom"] = round(out["ba_p50_ms_lines_custom"] / base, 2)
    return out


class _GtsamWithParams:
    """``gtsam`` with ``LevenbergMarquardtParams`` replaced (benchmark-only, for one replay)."""

    def __init__(self, make_params):
        self.LevenbergMarquardtParams = make_params

    def __getattr__(self, name):
        return getattr(gtsam, name)


class DarkenedSource:
    """A source whose rectified frames come out darkened by ``canopy.degrade.darken``
    (shot + read noise seeded per seed, frame and camera: same seed, same frames)."""

    def __init__(self, source, gain: float, seed: int):
        self.source = source
        self.calibration = source.calibration
        self.timestamps = source.timestamps
        self.ground_truth = source.ground_truth
        self.gain, self.seed = float(gain), int(seed)

    def __len__(self) -> int:
        return len(self.source)

    def frame(self, i: int) -> StereoFrame:
        f = self.source.frame(i)
        left = darken(f.left, self.gain, rng=np.random.default_rng([self.seed, i, 0]))
        right = darken(f.right, self.gain, rng=np.random.default_rng([self.seed, i, 1]))
        return StereoFrame(index=f.index, timestamp=f.timestamp, left=left, right=right)


def _robust_row(case: str, src) -> dict:
    row = {"case": case}
    for mode, on in (("points", False), ("points_lines", True)):
        r = run_mode(src, on)
        row[mode] = {k: r[k] for k in ("frames", "tracked", "lost", "first_lost", "keyframes", "ate_m",
                                       "ate_tracked_m", "map_lines")}
    p, pl = row["points"], row["points_lines"]
    row["lines_keep_tracking"] = bool(pl["tracked"] > p["tracked"] and pl["lost"] < p["lost"])
    return row


def robustness(args) -> list[dict]:
    rows = []
    for kind in DATASETS:
        src = open_source(kind)
        for gain in args.dark_gains:
            for seed in args.dark_seeds:
                rows.append(_robust_row(f"{kind} dark x{gain:g} seed {seed}", DarkenedSource(src, gain, seed)))
                print(_fmt_robust(rows[-1]), flush=True)
    if args.synthetic_light_ends:
        from canopy.synthetic import generate_sequence

        base = Path(args.synthetic_dir) if args.synthetic_dir else Path(tempfile.gettempdir()) / "canopy_bench_lines"
        for light_end in args.synthetic_light_ends:
            spec = dict(SYNTHETIC)
            preset, n, seed = spec.pop("preset"), spec.pop("n_frames"), spec.pop("seed")
            path = generate_sequence(preset, base / f"lowtex_light{light_end:g}", n_frames=n, seed=seed,
                                     light_end=light_end, **spec)
            rows.append(_robust_row(f"synthetic low-texture x>6 m, light 1 -> {light_end:g}",
                                    open_source("euroc", path)))
            print(_fmt_robust(rows[-1]), flush=True)
    return rows


def _fmt_robust(row: dict) -> str:
    p, pl = row["points"], row["points_lines"]
    return (f"{row['case']:44s} points {p['tracked']:3d}/{p['frames']} (first lost {p['first_lost']}, ATE {p['ate_m']}) | "
            f"+lines {pl['tracked']:3d}/{pl['frames']} (first lost {pl['first_lost']}, ATE {pl['ate_m']})"
            + ("  <- lines keep tracking" if row["lines_keep_tracking"] else ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_lines_slam.json"))
    ap.add_argument("--repeats", type=int, default=3, help="interleaved repeats of every timed run")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-robustness", action="store_true")
    ap.add_argument("--dark-gains", type=float, nargs="*", default=[0.2, 0.15])
    ap.add_argument("--dark-seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--synthetic-light-ends", type=float, nargs="*", default=[0.2, 0.18])
    ap.add_argument("--synthetic-dir", default=None, help="cache of generated sequences (default: a temp folder)")
    args = ap.parse_args()
    results = {"date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "machine": platform.processor()
               or platform.machine(), "python": platform.python_version(), "repeats": args.repeats, "datasets": {}}
    if not args.skip_speed:
        for kind in DATASETS:
            src = open_source(kind)
            entry = speed_and_accuracy(src, args.repeats)
            entry["ba_same_keyframes"] = ba_same_keyframes(src, args.repeats)
            results["datasets"][kind] = entry

        cols = ("tracked", "lost", "keyframes", "ate_m", "tracking_p50_ms", "tracking_p95_ms", "ba_p50_ms", "map_lines")
        print(f"{'dataset':8s} {'mode':13s} " + " ".join(f"{c:>15s}" for c in cols))
        for kind, e in results["datasets"].items():
            for mode in ("points", "points_lines"):
                print(f"{kind:8s} {mode:13s} " + " ".join(f"{str(e[mode][c]):>15s}" for c in cols))
            on = e["points_lines"]
            print(f"{kind:8s} lines add {e['lines_add_tracking_p50_ms']} ms to tracking p50 (per repeat "
                  f"{e['lines_add_tracking_p50_ms_runs']}); worker detect {on.get('lines_detect_worker_p50_ms')} + LBD "
                  f"{on.get('lines_describe_worker_p50_ms')} ms, main-thread wait {on.get('lines_wait_p50_ms')}, "
                  f"right lines wait {on.get('lines_right_wait_p50_ms')} (x{on.get('lines_right_wait_n', 0)}) / on demand "
                  f"{on.get('lines_right_on_demand_p50_ms')} (x{on.get('lines_right_on_demand_n', 0)}), line matching "
                  f"{on.get('line_match_p50_ms')} ms")
            b = e["ba_same_keyframes"]
            print(f"{kind:8s} BA p50 on the same {b['keyframes']} keyframes: points {b['ba_p50_ms_points']} ms, +lines "
                  f"projection {b['ba_p50_ms_lines_projection']} ms ({b['ratio_projection']}x, per repeat "
                  f"{b['ratio_projection_runs']}; {b['ratio_projection_equal_tol']}x vs points-only at the same LM "
                  f"tolerance), +lines custom {b['ba_p50_ms_lines_custom']} ms ({b['ratio_custom']}x)")
    if not args.skip_robustness:
        results["robustness"] = robustness(args)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
