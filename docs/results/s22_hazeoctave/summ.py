"""Per-draw ATE (mm) of Canopy auto on the KITTI g1 hazy cells, per setting folder (NAME/seedN.json), with the
draws better than `base` and under issue 9's bar (52.3 mm). Usage: python summ.py base md75 oct5 ..."""
import json, os, statistics, sys

HERE, BAR = os.path.dirname(os.path.abspath(__file__)), 52.3


def load(name):
    out = {}
    for s in range(3):
        f = os.path.join(HERE, name, f"seed{s}.json")
        if os.path.exists(f):
            for r in json.load(open(f))["rows"]:
                if r["method"] == "auto":
                    out[(r["cell"], s)] = (r["tracked_pct"], 1000 * r["ate_rmse_m"])
    return out


base = load("base")
for name in sys.argv[1:]:
    rows = load(name)
    for cell in sorted({c for c, _ in rows}):
        v = [rows[(cell, s)] for s in range(3) if (cell, s) in rows]
        b = [base.get((cell, s), (0, float("nan")))[1] for s in range(3) if (cell, s) in rows]
        txt = " / ".join(f"{a:.1f}" + ("" if t == 100 else f" ({t:.0f} %)") for t, a in v)
        better = sum(a < bb for (_, a), bb in zip(v, b))
        print(f"{name:8s} {cell:14s} {txt:22s} median {statistics.median(a for _, a in v):5.1f}  "
              f"better than base {better}/{len(v)}  bar {sum(a <= BAR for _, a in v)}/{len(v)}")
