"""s28-travel: one row per matrix.sh output file: ATE mm per cell (high-noise seeds, then low-noise), the means per
sensor and the mean Sim(3) ATE.

    python docs/results/s28_travel/summ.py OFF.txt ON.txt
"""
import sys, json, re, numpy as np
for f in sys.argv[1:]:
    rows=[]
    for line in open(f):
        name, js = line.split(' ',1)
        d=json.loads(js.split('}')[0]+'}')
        rows.append((name.replace('kitti-all-g1-b0.06-','').replace('-stereo-sky',''), d['ate']*1000, d['ate_sim3']*1000))
    hi=[r[1] for r in rows if 'high' in r[0]]; lo=[r[1] for r in rows if 'low' in r[0]]
    print(f"{f.split('/')[-1]:24s}", ' '.join(f"{r[1]:6.1f}" for r in rows), f"| mean hi {np.mean(hi):.1f} lo {np.mean(lo):.1f} | sim3 mean {np.mean([r[2] for r in rows]):.1f}")
print(' '*24, ' '.join(f"{r[0][:6]:>6s}" for r in rows))
