"""s30-offset: KITTI grid cells over noise draws, the old disparity offsets (pairs: cells 0.151, opencv 0.2 px)
against the map-calibrated ones (cells 0.100, opencv 0.16), with ORB-SLAM3 on the raw frames of each draw
(median of 3 runs where run here). ATE mm (tracked % where below 100), mean over the draws.

    python docs/results/s30_offset/draws_table.py            # the table of docs/notes/s30-offset.md
    python docs/results/s30_offset/draws_table.py --final    # + the noisy-frame ThDepth variant (off)
"""
import collections
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
CELLS = ["g1-b0-high", "g1-b0.06-high", "g0.15-b0-high", "g0.15-b0.06-high",
         "g1-b0-low", "g1-b0.06-low", "g0.15-b0-low", "g0.15-b0.06-low"]


def rows(path):
    return json.loads(Path(path).read_text())["rows"]


ate = collections.defaultdict(dict)      # (cell, variant) -> {seed: row}
orb = collections.defaultdict(dict)      # cell -> {seed: m}
for v, path in (("old", ROOT / "docs/results/s28_travel/grid_kitti_seed0.json"),
                ("new", HERE / "grid/grid_kitti_seed0.json"), ("final", HERE / "grid/grid_kitti_seed0_noisy_thdepth.json")):
    for r in rows(path):
        if r["dataset"] == "kitti" and r["method"] == "auto":
            ate[(r["cell"], v)][0] = r
for f in sorted((HERE / "draws").glob("kitti_*_s*.json")):
    v, s = f.stem.split("_")[1], int(f.stem.split("_s")[1].split("_")[0])
    for r in rows(f):
        if r["method"] == "auto":
            ate[(r["cell"], v)][s] = r
for f in sorted((HERE / "draws").glob("orb_kitti_*_s*.json")):
    s = int(f.stem.split("_s")[-1])
    for r in rows(f):
        if r["method"] == "orbslam3-raw":
            orb[r["cell"]][s] = r["ate_rmse_m"]
for r in rows(ROOT / "docs/results/bench_degrade_grid.json"):   # the grid's own draw (seed 0)
    if r["dataset"] == "kitti" and r["method"] == "orbslam3-raw":
        orb[r["cell"]][0] = r["ate_rmse_m"]


def fmt(r):
    if r is None:
        return "·"
    a, t = r.get("ate_rmse_m"), r.get("tracked_pct") or 0.0
    return ("-" if a is None else f"{1000 * a:.1f}") + ("" if t >= 99.99 else f" ({t:.0f} %)")


variants = ("old", "new", "final") if "--final" in sys.argv else ("old", "new")
print("| cell | offsets | seeds 0 / 1 / 2 / 3 / 4 / 5 / 6 | mean | ≥ ORB-SLAM3 raw |")
print("|---|---|---|---|---|")
for c in CELLS:
    for v in variants:
        d = ate.get((c, v), {})
        vals = [d.get(s) for s in range(7)]
        a = [x["ate_rmse_m"] for x in vals if x is not None and x.get("ate_rmse_m") is not None]
        wins = [x["ate_rmse_m"] <= orb[c][s] for s, x in enumerate(vals)
                if x is not None and x.get("ate_rmse_m") is not None and orb[c].get(s)]
        print(f"| {c} | {v} | " + " / ".join(fmt(x) for x in vals) + f" | {1000 * np.mean(a):.1f} | "
              + (f"{sum(wins)} of {len(wins)}" if wins else "–") + " |")
    if orb.get(c):
        print(f"| {c} | ORB-SLAM3 raw | " + " / ".join("·" if orb[c].get(s) is None else f"{1000 * orb[c][s]:.1f}"
                                                     for s in range(7)) + " | | |")
