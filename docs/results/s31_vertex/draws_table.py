"""s31-vertex: the noisy sensor's lit KITTI cells over seven noise draws, before (s30: the smoothed pair's
SAD vertex) and after (``tracking.subpixel_raw_vertex_search`` 2: the raw pair's vertex around the smoothed
minimum), with ORB-SLAM3 on the raw frames of each draw: median of 3 runs, in the same run as the "after" row
(``--peers raw --peer-reps 3``), and s30's runs beside the "before" row.
ATE mm, mean over the draws; the bar is 1.5 x the clean run (21.4 mm).

    python docs/results/s31_vertex/draws_table.py
"""
import collections
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
S30 = HERE.parent / "s30_offset"
CELLS = ["g1-b0-high", "g1-b0.06-high"]
BAR_MM = 1.5 * 21.4


def rows(path):
    return json.loads(Path(path).read_text())["rows"]


ate = collections.defaultdict(dict)      # (cell, variant) -> {seed: mm}
orb = collections.defaultdict(dict)      # cell -> {seed: mm}
for r in rows(S30 / "grid/grid_kitti_seed0.json"):
    if r["method"] == "auto" and r["cell"] in CELLS:
        ate[(r["cell"], "before")][0] = 1000 * r["ate_rmse_m"]
for f in sorted((S30 / "draws").glob("kitti_new_s*.json")):
    for r in rows(f):
        if r["method"] == "auto":
            ate[(r["cell"], "before")][int(f.stem.split("_s")[1])] = 1000 * r["ate_rmse_m"]
orb_s30 = collections.defaultdict(dict)  # cell -> {seed: mm}, s30's runs
for f in sorted((HERE / "draws").glob("kitti_g1_high_s*.json")):
    for r in rows(f):
        seed = int(f.stem.split("_s")[1])
        if r["method"] == "auto":
            ate[(r["cell"], "after")][seed] = 1000 * r["ate_rmse_m"]
        elif r["method"] == "orbslam3-raw" and r.get("ate_rmse_m") is not None:
            orb[r["cell"]][seed] = 1000 * r["ate_rmse_m"]
for f in sorted((S30 / "draws").glob("orb_kitti_*_s*.json")):
    for r in rows(f):
        if r["method"] == "orbslam3-raw" and r.get("ate_rmse_m") is not None:
            orb_s30[r["cell"]][int(f.stem.split("_s")[-1])] = 1000 * r["ate_rmse_m"]
for r in rows(HERE.parent / "bench_degrade_grid.json"):   # the grid's own draw (seed 0)
    if r["dataset"] == "kitti" and r["method"] == "orbslam3-raw" and r.get("ate_rmse_m") is not None:
        orb_s30[r["cell"]].setdefault(0, 1000 * r["ate_rmse_m"])

print(f"| cell | vertex | seeds 0 / 1 / 2 / 3 / 4 / 5 / 6 | mean | under the bar ({BAR_MM:.1f}) | ≥ ORB-SLAM3 raw |")
print("|---|---|---|---|---|---|")
for c in CELLS:
    for v in ("before", "after"):
        d = ate[(c, v)]
        vals = [d.get(s) for s in range(7)]
        got = [x for x in vals if x is not None]
        peer = orb[c] if v == "after" else orb_s30[c]
        beat = sum(1 for s, x in d.items() if s in peer and x <= peer[s])
        print(f"| {c} | {v} | " + " / ".join("·" if x is None else f"{x:.1f}" for x in vals)
              + f" | {np.mean(got):.1f} | {sum(x <= BAR_MM for x in got)} of {len(got)} | {beat} of "
              f"{sum(1 for s in d if s in peer)} |")
    for name, peer in (("ORB-SLAM3 raw, s30's runs", orb_s30[c]), ("ORB-SLAM3 raw, same run as after", orb[c])):
        print(f"| {c} | {name} | " + " / ".join(f"{peer[s]:.1f}" if s in peer else "·" for s in range(7))
              + f" | {np.mean(list(peer.values())):.1f} | | |")
