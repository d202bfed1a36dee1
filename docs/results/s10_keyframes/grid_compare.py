import json, sys
def rows(p):
    return {r['cell']: r for r in json.load(open(p))['rows'] if r['dataset'] == 'kitti' and r['method'] == 'auto'}
ref = rows(sys.argv[1]); new = rows(sys.argv[2])
print(f"{'cell':18s} {'ref ATE':>9s} {'ref trk':>7s} {'new ATE':>9s} {'new trk':>7s}")
f = lambda v: '-' if v is None else f"{v:.4f}"
for c in new:
    a, b = ref.get(c, {}), new[c]
    print(f"{c:18s} {f(a.get('ate_rmse_m')):>9s} {a.get('tracked_pct', float('nan')):7.1f} {f(b.get('ate_rmse_m')):>9s} {b['tracked_pct']:7.1f}")
