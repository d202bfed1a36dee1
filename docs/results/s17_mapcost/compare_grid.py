"""Grid rows of a run (its bench_degrade_grid.json) against the committed grid, per dataset and cell,
method auto: tracked % and ATE, and whether they agree to the digit.

    python docs/results/s17_mapcost/compare_grid.py RUN.json [docs/results/bench_degrade_grid.json]
"""
import json, sys

run = json.load(open(sys.argv[1]))["rows"]
ref = json.load(open(sys.argv[2] if len(sys.argv) > 2 else "docs/results/bench_degrade_grid.json"))["rows"]
key = lambda r: (r["dataset"], r["cell"], r["method"])
refd = {key(r): r for r in ref}
same = diff = 0
for r in run:
    if r["method"] != "auto":
        continue
    o = refd.get(key(r))
    if o is None:
        print(f"{r['dataset']:6s} {r['cell']:18s} no reference row")
        continue
    eq = (r.get("ate_rmse_m") == o.get("ate_rmse_m")) and (r.get("tracked_pct") == o.get("tracked_pct"))
    same += eq
    diff += not eq
    f = lambda x: "None" if x is None else f"{x * 1e3:.4f} mm"
    print(f"{r['dataset']:6s} {r['cell']:18s} ref {o.get('tracked_pct'):5.1f}% {f(o.get('ate_rmse_m')):>14s}  run "
          f"{r.get('tracked_pct'):5.1f}% {f(r.get('ate_rmse_m')):>14s}  {'same' if eq else 'DIFFERENT'}")
print(f"{same} rows identical, {diff} different")
