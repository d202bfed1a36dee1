"""s29-scale: the preset runs' ATE (mm; tracked % where below 100) per cell, seeds found, one column per tag.
usage: python summ.py base ms6 ...   (reads presets/TAG_DATASET_sSEED.json, bench_degrade_grid.py's JSON)"""
import collections
import glob
import json
import os
import sys

here = os.path.dirname(os.path.abspath(__file__))
res = collections.defaultdict(dict)
for tag in sys.argv[1:]:
    for f in sorted(glob.glob(f"{here}/presets/{tag}_*_s*.json")):
        seed = f.rsplit("_s", 1)[1].split(".")[0]
        for r in json.load(open(f))["rows"]:
            if r["method"] != "auto":
                continue
            a, t = r.get("ate_rmse_m"), r.get("tracked_pct")
            v = "-" if a is None else f"{1000 * a:.1f}" + ("" if t is None or t >= 99.99 else f"({t:.0f}%)")
            res[(r["dataset"], r["cell"])].setdefault(tag, {})[seed] = v
seeds = sorted({s for r in res.values() for t in r.values() for s in t}, key=int)
print("seeds " + "/".join(seeds))
for k in sorted(res):
    print(f"{k[0]:10s} {k[1]:18s}", "  ".join(f"{t}: " + "/".join(res[k].get(t, {}).get(s, "?") for s in seeds)
                                              for t in sys.argv[1:]))
