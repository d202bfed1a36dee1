"""EuRoC grid: `auto` per variant against ORB-SLAM3 raw (the base run's), cell by cell (notes s9-lead).

    python docs/results/s9_lead/compare_euroc_variants.py 1200 cells cells1200
"""
import json, sys
base = json.load(open('docs/results/s9_lead/bench_degrade_grid_euroc_base.json'))['rows']
orb = {r['cell']: r for r in base if r['method'] == 'orbslam3-raw'}
cols = [('base', base)] + [(p, json.load(open(f'docs/results/s9_lead/bench_degrade_grid_euroc_{p}.json'))['rows']) for p in sys.argv[1:]]
def f(r): return f"{r.get('tracked_pct') or 0:5.1f}% {1000*r['ate_rmse_m']:.2f}" if r.get('ate_rmse_m') else f"{r.get('tracked_pct') or 0:5.1f}%  -  "
print("cell".ljust(18), "ORB raw".ljust(14), "  ".join(n.ljust(14) for n, _ in cols))
wins = {n: 0 for n, _ in cols}
for cell in [r['cell'] for r in base if r['method'] == 'auto']:
    o = orb[cell]; line = [f(o)]
    for n, rows in cols:
        a = next(r for r in rows if r['cell'] == cell and r['method'] == 'auto')
        ok = (a.get('tracked_pct') or 0) >= (o.get('tracked_pct') or 0) and (not a.get('ate_rmse_m') or not o.get('ate_rmse_m') or a['ate_rmse_m'] <= o['ate_rmse_m']) and not (a.get('ate_rmse_m') is None and o.get('ate_rmse_m'))
        wins[n] += ok and cell != 'clean'
        line.append(f(a) + (" ok" if ok else " NO"))
    print(cell.ljust(18), "  ".join(x.ljust(14) for x in line))
print(wins)
