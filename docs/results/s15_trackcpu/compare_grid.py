"""Rows of a grid run (``--out-dir``'s bench_degrade_grid.json) against the committed grid JSON:
tracked % and ATE, and whether equal to the last digit.

    python docs/results/s15_trackcpu/compare_grid.py /tmp/s15t/g/bench_degrade_grid.json
"""
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
main = {(r["dataset"], r["cell"], r["method"], r.get("runner")): r
        for r in json.load(open(ROOT / "docs/results/bench_degrade_grid.json"))["rows"]}
for path in sys.argv[1:]:
    for r in json.load(open(path))["rows"]:
        m = main.get((r["dataset"], r["cell"], r["method"], r.get("runner")))
        if m is None:
            print(f"{r['dataset']:10s} {r['cell']:18s} {r['method']:6s} (not in the committed grid)")
            continue
        same = m["tracked_pct"] == r["tracked_pct"] and m["ate_rmse_m"] == r["ate_rmse_m"]
        print(f"{r['dataset']:10s} {r['cell']:18s} {r['method']:6s} committed {m['tracked_pct']:5.1f} % {m['ate_rmse_m']!r:24}"
              f" this {r['tracked_pct']:5.1f} % {r['ate_rmse_m']!r:24} {'EQUAL' if same else 'DIFFERENT'}")
