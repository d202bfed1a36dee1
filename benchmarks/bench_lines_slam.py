"""Points only vs points + lines through the lockstep pipeline (issue 4, items 4-5).

Per dataset snippet (EuRoC V1_01 micro slice 752x480, KITTI 06 snippet 1226x370):

* ``run_sequential`` with ``use_lines`` off and on: frames tracked, lost frames, keyframes,
  ATE (SE(3)-aligned RMSE against ground truth), tracking total p50 / p95 (ms), the line
  stages (worker detection / LBD, which overlap ORB and stereo; the main-thread wait for
  them; temporal line matching), local-BA p50 per keyframe and map sizes.
* BA on the same keyframes: the keyframes of the points + lines run are replayed into a
  points-only mapper and a points + lines mapper (``projection`` and ``custom`` factors),
  BA p50 per keyframe and the ratio to points only (issue target <= 1.5x).

    python benchmarks/bench_lines_slam.py [--out results/bench_lines_slam.json]
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.backend import LocalMapper, MappingParams  # noqa: E402
from canopy.frontend import Tracker, TrackingParams  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import run_sequential  # noqa: E402
from canopy.sources import open_source  # noqa: E402

DATASETS = ("euroc", "kitti")
LINE_STAGES = ("lines_detect_worker", "lines_describe_worker", "lines_wait", "line_match")


def _p(summary: dict, key: str, q: str = "p50") -> float | None:
    return round(summary[key][q], 2) if key in summary else None


def run_mode(src, use_lines: bool) -> dict:
    res = run_sequential(src, TrackingParams(use_lines=use_lines), MappingParams(use_lines=use_lines))
    s = res.timing_summary()
    ate = ape(res.trajectory.poses, src.ground_truth.poses, align="se3")["rmse"] if src.ground_truth is not None else None
    out = {"frames": res.n_frames, "tracked": int(sum(st != "lost" for st in res.statuses)), "lost": res.n_lost,
           "keyframes": len(res.keyframe_indices), "ate_m": None if ate is None else round(float(ate), 4),
           "tracking_p50_ms": _p(s, "tracking.total"), "tracking_p95_ms": _p(s, "tracking.total", "p95"),
           "ba_p50_ms": _p(s, "mapping.ba"), "map_points": int(len(res.map_points)),
           "map_lines": int(len(res.map_lines))}
    out.update({f"{k}_p50_ms": _p(s, f"tracking.{k}") for k in LINE_STAGES if f"tracking.{k}" in s})
    return out


def ba_same_keyframes(src) -> dict:
    """Collect the keyframes of a points + lines run, replay them into three mappers."""
    calib = src.calibration
    tracker = Tracker(calib, TrackingParams(use_lines=True))
    mapper = LocalMapper(calib, MappingParams(use_lines=True))
    kfs = []
    for i in range(len(src)):
        res = tracker.track(src.frame(i))
        if res.is_keyframe and res.keyframe is not None:
            kfs.append(res.keyframe)
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
    out = {"keyframes": len(kfs)}
    for name, params in (("points", MappingParams()), ("lines_projection", MappingParams(use_lines=True)),
                         ("lines_custom", MappingParams(use_lines=True, line_factor="custom"))):
        m = LocalMapper(calib, params)
        ba = [m.insert_keyframe(kf).timings["ba"] for kf in kfs]
        out[f"ba_p50_ms_{name}"] = round(float(np.median(ba)), 2)
    base = out["ba_p50_ms_points"]
    out["ratio_projection"] = round(out["ba_p50_ms_lines_projection"] / base, 2)
    out["ratio_custom"] = round(out["ba_p50_ms_lines_custom"] / base, 2)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_lines_slam.json"))
    args = ap.parse_args()
    results = {"date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "machine": platform.processor()
               or platform.machine(), "python": platform.python_version(), "datasets": {}}
    for kind in DATASETS:
        src = open_source(kind)
        entry = {"points": run_mode(src, False), "points_lines": run_mode(src, True), "ba_same_keyframes": ba_same_keyframes(src)}
        off, on = entry["points"], entry["points_lines"]
        entry["lines_add_tracking_p50_ms"] = round(on["tracking_p50_ms"] - off["tracking_p50_ms"], 2)
        results["datasets"][kind] = entry

    cols = ("tracked", "lost", "keyframes", "ate_m", "tracking_p50_ms", "tracking_p95_ms", "ba_p50_ms", "map_lines")
    print(f"{'dataset':8s} {'mode':13s} " + " ".join(f"{c:>15s}" for c in cols))
    for kind, e in results["datasets"].items():
        for mode in ("points", "points_lines"):
            print(f"{kind:8s} {mode:13s} " + " ".join(f"{str(e[mode][c]):>15s}" for c in cols))
        on = e["points_lines"]
        print(f"{kind:8s} lines add {e['lines_add_tracking_p50_ms']} ms to tracking p50; worker detect "
              f"{on.get('lines_detect_worker_p50_ms')} + LBD {on.get('lines_describe_worker_p50_ms')} ms (overlapping "
              f"ORB/stereo), main-thread wait {on.get('lines_wait_p50_ms')}, line matching {on.get('line_match_p50_ms')} ms")
        b = e["ba_same_keyframes"]
        print(f"{kind:8s} BA p50 on the same {b['keyframes']} keyframes: points {b['ba_p50_ms_points']} ms, +lines "
              f"projection {b['ba_p50_ms_lines_projection']} ms ({b['ratio_projection']}x), +lines custom "
              f"{b['ba_p50_ms_lines_custom']} ms ({b['ratio_custom']}x)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
