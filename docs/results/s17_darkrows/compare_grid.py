#!/usr/bin/env python
"""Grid rows of one or more bench_degrade_grid.json files beside main's (docs/results/bench_degrade_grid.json):
per (dataset, cell, method) tracked % and ATE (mm), and whether they are the same to 1e-9 m.

    python docs/results/s17_darkrows/compare_grid.py /tmp/dr/grid_lv/*/bench_degrade_grid.json
"""
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def rows(path):
    return {(r["dataset"], r["cell"], r["method"]): r for r in json.load(open(path))["rows"]
            if not r["method"].startswith("orbslam3")}


def fmt(r):
    if r is None:
        return "-"
    a = r.get("ate_rmse_m")
    return f"{r['tracked_pct']:.1f} % {a * 1e3:.2f} mm" if a is not None else f"{r['tracked_pct']:.1f} % -"


main = rows(ROOT / "docs/results/bench_degrade_grid.json")
for p in sys.argv[1:]:
    for k, r in rows(p).items():
        m = main.get(k)
        a, b = (None if m is None else m.get("ate_rmse_m")), r.get("ate_rmse_m")
        # equal to 1e-9 m: the same run reproduces main's figure to ~1e-15 m on another machine's BLAS
        same = (m is not None and m["tracked_pct"] == r["tracked_pct"]
                and (a == b or (a is not None and b is not None and abs(a - b) < 1e-9)))
        print(f"{k[0]:10s} {k[1]:18s} {k[2]:5s} main {fmt(m):22s} new {fmt(r):22s} {'=' if same else 'CHANGED'}")
