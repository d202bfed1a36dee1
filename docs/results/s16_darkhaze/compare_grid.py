#!/usr/bin/env python
"""s16-darkhaze: a grid JSON's `auto` rows against main's (docs/results/bench_degrade_grid.json): ATE /
tracked per cell, the issue-9 verdicts with main's clean row and ORB-SLAM3 raw columns. Usage:
    python compare_grid.py RUN.json [DATASET]"""
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
main = json.load(open(ROOT / "docs/results/bench_degrade_grid.json"))["rows"]
run = json.load(open(sys.argv[1]))["rows"]
want = sys.argv[2] if len(sys.argv) > 2 else None


def key(r):
    return r["dataset"], r["cell"], r["method"]


mrows = {key(r): r for r in main}
fmt = lambda r: "—" if r is None else (f"{r['tracked_pct']:.0f} %" if not r.get("ate_rmse_m") else (  # noqa: E731
    f"{1000 * r['ate_rmse_m']:.2f}" + ("" if r["tracked_pct"] == 100 else f" ({r['tracked_pct']:.0f} %)")))
counts = {"main": [0, 0, 0, 0], "run": [0, 0, 0, 0]}
for r in run:
    if r["method"] != "auto" or (want and r["dataset"] != want):
        continue
    m = mrows.get(key(r))
    clean = mrows.get((r["dataset"], "clean", "auto"))
    orb = mrows.get((r["dataset"], r["cell"], "orbslam3-raw"))
    line = f"| {r['dataset']} | {r['cell']} | {fmt(m)} | {fmt(r)} | {fmt(orb)} |"
    if r["cell"] != "clean" and orb is not None and clean is not None:
        half = orb["tracked_pct"] >= 50
        for name, row in (("main", m), ("run", r)):
            ok_bar = row["tracked_pct"] == 100 and row["ate_rmse_m"] is not None and \
                row["ate_rmse_m"] <= 1.5 * clean["ate_rmse_m"]
            at_least = row["tracked_pct"] >= orb["tracked_pct"] and (
                orb["ate_rmse_m"] is None or row["tracked_pct"] > orb["tracked_pct"] or
                (row["ate_rmse_m"] is not None and row["ate_rmse_m"] <= orb["ate_rmse_m"]))
            if half:
                counts[name][0] += ok_bar
                counts[name][1] += 1
            counts[name][2] += at_least
            counts[name][3] += 1
        line += f" {'bar cell' if half else ''}"
    print(line)
for name, (b, nb, a, na) in counts.items():
    print(f"{name}: bar {b}/{nb}, at least ORB-SLAM3 raw {a}/{na}")
