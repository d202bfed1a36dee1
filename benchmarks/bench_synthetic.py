#!/usr/bin/env python
"""SLAM on the generated orchard sequences, through the real multi-process system.

Rows: ``day-loop`` with no enhancement (the whole loop, revisit included), and
``dusk-loop`` and ``haze-row`` for each enhancement method. Each run is
``canopy.app.run_slam(dataset="synthetic", preset=..., enhance=..., clock="lockstep")``:
the generated sequence (cached in cache/synthetic/) is read by the EuRoC
source and measured against its exact ground truth.

    python benchmarks/bench_synthetic.py                       # full lengths
    python benchmarks/bench_synthetic.py --frames 300          # quicker
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

METHODS = ("none", "clahe", "afe", "agri", "auto")


def one_run(preset: str, method: str, frames: int | None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.monotonic()
        res = run_slam("synthetic", preset=preset, enhance=method, max_frames=frames, clock="lockstep",
                       out=str(Path(tmp) / "run"), progress=False)
        wall = time.monotonic() - t0
    m, s = res.summary["metrics"], res.summary["stats"]
    t = m["tracking"]
    return {"preset": preset, "method": method, "ok": res.outcome.ok, "outcome": res.outcome.reason,
            "frames": t["frames_processed"], "frames_total": t["frames_total"], "lost": t["frames_lost"],
            "success_percent": t["tracking_success_percent"], "keyframes": t["keyframes"],
            "ate_rmse_m": (m.get("ate") or {}).get("rmse"), "path_m": (m.get("gt_motion") or {}).get("path_length_m"),
            "kitti": m.get("kitti"), "tracking_p50_ms": s.get("tracking", {}).get("service_ms", {}).get("p50"),
            "methods_used": s.get("enhancement", {}).get("extra", {}).get("methods"), "wall_s": wall}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=None, help="frames per sequence (default: the preset's length)")
    ap.add_argument("--methods", nargs="+", default=list(METHODS))
    ap.add_argument("--presets", nargs="+", default=["dusk-loop", "haze-row"])
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_synthetic.json"))
    args = ap.parse_args()
    rows = [one_run("day-loop", "none", args.frames)]
    print(f"  day-loop/none: {rows[-1]['wall_s']:.0f} s", file=sys.stderr)
    for preset in args.presets:
        for method in args.methods:
            rows.append(one_run(preset, method, args.frames))
            print(f"  {preset}/{method}: {rows[-1]['wall_s']:.0f} s", file=sys.stderr)
    print(f"\nCanopy SLAM on generated orchard sequences — {os.cpu_count()} cores, Python {platform.python_version()}")
    hdr = f"{'preset':10s} {'method':6s} {'frames':>9s} {'lost':>5s} {'track %':>7s} {'KF':>4s} {'path m':>7s} {'ATE m':>7s} {'t_rel %':>7s} {'trk p50':>7s}  decisions"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        ate = "-" if r["ate_rmse_m"] is None else f"{r['ate_rmse_m']:.3f}"
        trel = (r["kitti"] or {}).get("t_rel_percent")
        print(f"{r['preset']:10s} {r['method']:6s} {r['frames']:>4d}/{r['frames_total']:<4d} {r['lost']:>5d} "
              f"{r['success_percent']:>7.1f} {r['keyframes']:>4d} {r['path_m'] or 0:>7.1f} {ate:>7s} "
              f"{'-' if trel is None else f'{trel:.2f}':>7s} {r['tracking_p50_ms'] or 0:>7.1f}  {r['methods_used']}")
    out = write_json(args.out, {"cpu_count": os.cpu_count(), "frames": args.frames, "rows": rows,
                                "time": time.strftime("%Y-%m-%d %H:%M:%S")})
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
