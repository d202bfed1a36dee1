#!/usr/bin/env python
"""End-to-end SLAM benchmark: both bundled sequences, lockstep and realtime.

Runs the real multi-process system (the same path as launch.py) and prints one
table: frames/s, tracking service time p50/p95, every actor's service time,
CPU and peak RSS, dropped frames, ATE. Writes everything to JSON.

    python benchmarks/bench_slam.py                # all four runs
    python benchmarks/bench_slam.py --datasets kitti --clocks lockstep
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.app import run_slam  # noqa: E402
from canopy.report import write_json  # noqa: E402

ACTORS = ("source", "enhancement", "tracking", "local_mapping")


def one_run(dataset: str, clock: str, enhance: str | None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        res = run_slam(dataset, clock=clock, enhance=enhance, out=str(Path(tmp) / "run"), progress=False)
    m, s = res.summary["metrics"], res.summary["stats"]
    row = {"dataset": dataset, "clock": clock, "enhance": enhance or "config", "ok": res.outcome.ok,
           "outcome": res.outcome.reason, "frames": m["tracking"]["frames_processed"],
           "frames_total": m["tracking"]["frames_total"], "lost": m["tracking"]["frames_lost"],
           "keyframes": m["tracking"]["keyframes"], "wall_s": res.outcome.wall_s,
           "fps": m["run"]["frames_per_s"], "ate_rmse_m": (m.get("ate") or {}).get("rmse"),
           "est_motion": m.get("est_motion"), "kitti": m.get("kitti"),
           "dropped": {a: s[a]["dropped"] for a in s}, "actors": s}
    return row


def fmt(v, spec=".1f"):
    return "-" if v is None else format(v, spec)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--datasets", nargs="+", default=["euroc", "kitti"])
    ap.add_argument("--clocks", nargs="+", default=["lockstep", "realtime"])
    ap.add_argument("--enhance", default=None, help="override the config's enhancement method")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_slam.json"))
    args = ap.parse_args()
    rows = []
    for ds in args.datasets:
        for clock in args.clocks:
            t0 = time.monotonic()
            rows.append(one_run(ds, clock, args.enhance))
            print(f"  {ds}/{clock}: {time.monotonic() - t0:.1f} s", file=sys.stderr)
    cores = os.cpu_count()
    hdr = (f"{'run':18s} {'frames':>7s} {'lost':>4s} {'KF':>3s} {'fps':>6s} {'ATE m':>7s} {'drops':>5s} | "
           + " | ".join(f"{a[:10]:>10s} p50/p95 ms" for a in ACTORS) + " | CPU% src/enh/trk/map | RSS MB trk/map")
    print(f"\nCanopy SLAM benchmark — {cores} cores, {platform.processor() or platform.machine()}, "
          f"Python {platform.python_version()}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        a = r["actors"]
        lat = " | ".join(f"{fmt(a.get(n, {}).get('service_ms', {}).get('p50')):>10s}/"
                         f"{fmt(a.get(n, {}).get('service_ms', {}).get('p95')):<6s}     " for n in ACTORS)
        cpu = "/".join(fmt(a.get(n, {}).get("cpu_percent", {}).get("mean"), ".0f") for n in ACTORS)
        rss = "/".join(fmt(a.get(n, {}).get("peak_rss_mb"), ".0f") for n in ("tracking", "local_mapping"))
        drops = sum(r["dropped"].values())
        print(f"{r['dataset'] + '/' + r['clock']:18s} {r['frames']:>4d}/{r['frames_total']:<3d}{r['lost']:>3d} "
              f"{r['keyframes']:>3d} {fmt(r['fps']):>6s} {fmt(r['ate_rmse_m'], '.3f'):>7s} {drops:>5d} | {lat}| "
              f"{cpu:>19s} | {rss}")
    out = write_json(args.out, {"cpu_count": cores, "machine": platform.platform(), "rows": rows,
                                "time": time.strftime("%Y-%m-%d %H:%M:%S")})
    print(f"\nwrote {out}")
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
