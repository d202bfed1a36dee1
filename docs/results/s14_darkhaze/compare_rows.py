#!/usr/bin/env python
"""s14-darkhaze: the KITTI auto rows of grid JSONs side by side (ATE mm, tracked %), the first file as
the reference; usage: compare_rows.py ref.json other.json [...]"""
import json
import sys


def rows(path):
    d = json.load(open(path))
    return {r["cell"]: r for r in d["rows"] if r["dataset"] == "kitti" and r["method"] == "auto"}


def fmt(r):
    if r is None:
        return "-"
    a = r.get("ate_rmse_m")
    t = r.get("tracked_pct") or 0.0
    s = "–" if a is None else f"{1000 * a:.1f}"
    return s if t >= 99.99 else f"{t:.0f} %, {s}"


tabs = [rows(p) for p in sys.argv[1:]]
cells = list(tabs[0]) + [c for t in tabs[1:] for c in t if c not in tabs[0]]
for c in cells:
    print(f"{c:18s}", " | ".join(f"{fmt(t.get(c)):>14s}" for t in tabs))
