import json, glob, os, re, collections
vals = collections.defaultdict(dict)
for f in glob.glob('/tmp/attitude/grid/*/bench_degrade_grid.json') + glob.glob('/tmp/attitude/base-*/bench_degrade_grid.json'):
    name = os.path.basename(os.path.dirname(f))
    d = json.load(open(f))
    for r in d['rows']:
        if r.get('method') != 'auto':
            continue
        m = re.match(r'base-(dl|dr)-s(\d)$', name)
        if m:   # /tmp/attitude/base-dl-s0 etc (the first baselines)
            cfg = 'base'; cell = {'dl': 'dl015b006', 'dr': 'dr1b006'}[m.group(1)]; s = m.group(2)
        else:
            cfg, cell, s = re.match(r'(\w+?)-(\w+)-s(\d)$', name).groups()
            cfg = 'ba1' if cfg == 'real' else cfg
        pct = r['tracked_pct']
        vals[(cell, cfg)][int(s)] = (r['ate_rmse_m'] * 1e3, pct)
cells = ['dl015b006', 'dl015b0', 'dl1b006', 'dl1b0', 'dr1b006', 'dr1b0', 'hr1b006', 'hr1b0']
cfgs = ['base', 'real', 'ba1', 'trk1', 'ba2', 'trk2', 'ref5', 'sig03']
for c in cells:
    for g in cfgs:
        v = vals.get((c, g))
        if v:
            print(f"{c:10s} {g:6s} " + " / ".join(f"{v[s][0]:.2f}" + ("" if v[s][1] == 100 else f"({v[s][1]:.0f}%)") if s in v else "-" for s in range(3)))
