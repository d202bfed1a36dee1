"""s29-scale: the offset sweep's lines (offset_sweep.sh) beside the shipped config's (s28's matrix.sh lines, or
the sweep's delta 0), as a table of ATE mm (Sim(3) scale) per cell and delta.  usage: sweep_table.py FILE..."""
import collections
import json
import sys

rows = collections.defaultdict(dict)
for f in sys.argv[1:]:
    for line in open(f):
        parts = line.split()
        cell = parts[0].replace("kitti-all-g1-b0.06-", "").replace("-stereo-sky", "")
        delta = float(parts[2]) if parts[1] == "delta" else 0.0
        js = line[line.index("{"):line.index("}") + 1]
        d = json.loads(js)
        rows[cell][delta] = f"{1000 * d['ate']:.1f} ({d['scale']:.4f})"
deltas = sorted({d for r in rows.values() for d in r})
print("cell".ljust(12), "  ".join(f"delta {d:+.2f} px".ljust(18) for d in deltas))
for cell in sorted(rows, key=lambda c: (c.split("-")[0], int(c.split("seed")[1]))):
    print(cell.ljust(12), "  ".join(rows[cell].get(d, "-").ljust(18) for d in deltas))
