#!/usr/bin/env python
"""Lockstep throughput through the actors, before / after pipelining (issue 8: speed).

Runs ``launch``'s ``run_slam`` on the same frames with variants of the dataset's shipped config,
interleaved A B A B (a shared machine's load falls on every variant alike), and prints one table:
ATE, keyframes, pose rate (poses per second between the first and the last pose), run wall
time, tracking service p50 (the per-frame figure held against ORB-SLAM3's ``track_stereo()``)
and the CPU seconds of tracking and local mapping. JSON in ``docs/results/bench_pipelining.json``.

Variants (``--variant "name:section.key=value,..."``; the shipped config is always "shipped"):
by default "waiting" (``runtime.map_update_lag_frames=0``, ``runtime.lockstep_prefetch_frames=0``:
every keyframe's local BA is waited for before the next frame is read, as before pipelining).

    python benchmarks/bench_pipelining.py --dataset kitti --reps 3
    python benchmarks/bench_pipelining.py --dataset kitti --reps 3 \\
        --variant "before:runtime.map_update_lag_frames=0,runtime.lockstep_prefetch_frames=0,tracking.n_features=2000"
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from canopy.app import run_slam  # noqa: E402
from canopy.config import default_config_path, parse_variant  # noqa: E402
from canopy.report import write_json  # noqa: E402

DEFAULT_VARIANTS = ("waiting:runtime.map_update_lag_frames=0,runtime.lockstep_prefetch_frames=0",)


def _config_file(dataset: str, sets, folder: Path, heartbeat_s: float) -> Path:
    cfg = yaml.safe_load(default_config_path(dataset).read_text()) or {}
    cfg.setdefault("runtime", {})["heartbeat_timeout_s"] = heartbeat_s  # a loaded machine is not a hang
    for section, field, value in sets:
        cfg.setdefault(section, {})[field] = value
    path = folder / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def one_run(dataset: str, sets, max_frames: int | None, loop: bool, heartbeat_s: float) -> dict:
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        config = _config_file(dataset, sets, Path(tmp), heartbeat_s)
        res = run_slam(dataset, config=str(config), out=str(Path(tmp) / "run"), progress=False,
                       max_frames=max_frames, loop=loop)
    m, stats = res.summary["metrics"], res.summary["stats"]
    tracking = stats["tracking"]
    extra = tracking.get("extra", {})
    cpu_s = {a: s["cpu_percent"]["mean"] / 100.0 * m["run"]["wall_s"] for a, s in stats.items()}
    return {"ok": res.outcome.ok, "outcome": res.outcome.reason, "load_1min": load,
            "ate_m": (m.get("ate") or {}).get("rmse"), "keyframes": extra.get("keyframes"),
            "pose_rate_hz": (m.get("end_to_end_ms") or {}).get("pose_rate_hz"), "wall_s": m["run"]["wall_s"],
            "tracking_service_ms_p50": tracking["service_ms"]["p50"],
            "local_mapping_service_ms_p50": stats["local_mapping"]["service_ms"]["p50"],
            "cpu_s_approx": cpu_s}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="kitti", choices=("kitti", "euroc"))
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--variant", action="append", default=None, help='"name:section.key=value,..."')
    ap.add_argument("--loop", action="store_true", help="keep loop closing on (off by default: one actor fewer)")
    ap.add_argument("--heartbeat-s", type=float, default=60.0)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "bench_pipelining.json")
    a = ap.parse_args()
    variants = [("shipped", [])] + [parse_variant(v) for v in (a.variant or DEFAULT_VARIANTS)]
    runs: dict[str, list[dict]] = {name: [] for name, _ in variants}
    for rep in range(a.reps):
        for name, sets in variants:  # A B A B
            r = one_run(a.dataset, sets, a.max_frames, a.loop, a.heartbeat_s)
            runs[name].append(r)
            print(f"rep {rep + 1} {name:10s} load {r['load_1min']:5.1f} pose rate {r['pose_rate_hz'] or 0:6.2f}/s "
                  f"tracking p50 {r['tracking_service_ms_p50']:6.1f} ms ATE {r['ate_m'] or 0:.4f} m "
                  f"{'' if r['ok'] else r['outcome']}", flush=True)
    med = lambda rs, k: statistics.median([r[k] for r in rs if r.get(k) is not None]) if rs else None  # noqa: E731
    rows = []
    for name, sets in variants:
        rs = [r for r in runs[name] if r["ok"]]
        rows.append({"variant": name, "sets": [f"{s}.{f}={v}" for s, f, v in sets], "runs": len(rs),
                     **{k: med(rs, k) for k in ("ate_m", "keyframes", "pose_rate_hz", "wall_s",
                                                "tracking_service_ms_p50", "local_mapping_service_ms_p50")},
                     "cpu_s_tracking": med([{"v": r["cpu_s_approx"]["tracking"]} for r in rs], "v"),
                     "cpu_s_local_mapping": med([{"v": r["cpu_s_approx"]["local_mapping"]} for r in rs], "v")})
    fmt = lambda v, s=".1f": "-" if v is None else format(v, s)  # noqa: E731
    print(f"\n{a.dataset}, lockstep through the actors, {a.reps} interleaved reps, medians "
          f"({os.cpu_count()} cores; load 1 min {min(r['load_1min'] for rs in runs.values() for r in rs):.1f}-"
          f"{max(r['load_1min'] for rs in runs.values() for r in rs):.1f})")
    print(f"{'variant':10s} {'runs':>4s} {'ATE m':>7s} {'kf':>4s} {'poses/s':>8s} {'wall s':>7s} "
          f"{'track p50':>9s} {'map p50':>8s} {'trk cpu s':>9s} {'map cpu s':>9s}")
    for r in rows:
        print(f"{r['variant']:10s} {r['runs']:4d} {fmt(r['ate_m'], '.4f'):>7s} {fmt(r['keyframes'], '.0f'):>4s} "
              f"{fmt(r['pose_rate_hz'], '.2f'):>8s} {fmt(r['wall_s']):>7s} {fmt(r['tracking_service_ms_p50']):>9s} "
              f"{fmt(r['local_mapping_service_ms_p50']):>8s} {fmt(r['cpu_s_tracking'], '.2f'):>9s} "
              f"{fmt(r['cpu_s_local_mapping'], '.2f'):>9s}")
    write_json(a.out, {"dataset": a.dataset, "reps": a.reps, "max_frames": a.max_frames, "loop": a.loop,
                       "date": time.strftime("%Y-%m-%d %H:%M"), "command": " ".join(sys.argv),
                       "cpu_count": os.cpu_count(), "rows": rows, "runs": runs,
                       "note": "lockstep; wall figures depend on the machine's load (load_1min per run)"})
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
