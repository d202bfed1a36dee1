import json, glob, os, re, collections, sys
vals = collections.defaultdict(dict)
for f in glob.glob('/tmp/gate/grid/*/bench_degrade_grid.json'):
    name = os.path.basename(os.path.dirname(f))
    m = re.match(r'(\w+?)-(\w+)-s(\d)$', name)
    if not m: continue
    cfg, cell, s = m.groups()
    for r in json.load(open(f))['rows']:
        if r.get('method') != 'auto' or r.get('ate_rmse_m') is None: continue
        vals[(cell, cfg)][int(s)] = (r['ate_rmse_m'] * 1e3, r['tracked_pct'])
opens = {}
for f in glob.glob('/tmp/gate/*-s[012].log'):
    name = os.path.basename(f)[:-4]
    t = open(f).read()
    opens[name] = f"{t.count('open 1')}/{t.count('VGATE')}"
cells = ['dl015b006', 'dl015b0', 'dl1b006', 'dl1b0', 'dr1b006', 'dr1b0', 'hr1b006']
for c in cells:
    for g in sorted({k[1] for k in vals if k[0] == c}):
        v = vals[(c, g)]
        print(f"{c:10s} {g:6s} " + " / ".join((f"{v[s][0]:.2f}" + ("" if v[s][1] == 100 else f"({v[s][1]:.0f}%)") + f" [{opens.get(f'{g}-{c}-s{s}','')}]") if s in v else "-" for s in range(3)))
