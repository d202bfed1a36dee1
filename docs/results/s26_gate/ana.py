import re,glob,numpy as np,sys
pat=sys.argv[1] if len(sys.argv)>1 else 'sig2'
for f in sorted(glob.glob(f'/tmp/gate/{pat}-*.log')):
    rows=[]
    for l in open(f):
        if not l.startswith('VGATE'): continue
        t=l.split()
        d=dict(zip(t[1::2],t[2::2]))
        # far40 N S far70 N S far90 N S
        m=re.findall(r'far(\d+) (\d+) (\S+)',l)
        rows.append([float(d['n']),float(d['vision']),float(d['up'])]+[float(x) for mm in m[-3:] for x in mm[1:]])
    a=np.array(rows); up=a[:,2]
    out=f"{f.split('/')[-1][len(pat)+1:-4]:14s} kf {len(a):3d}"
    for k,D in enumerate((40,70,90)):
        n=a[:,3+2*k]; s=a[:,4+2*k]; r=s/up
        out+=f" | D{D} n p10/50/90 {np.percentile(n,10):4.0f} {np.percentile(n,50):4.0f} {np.percentile(n,90):4.0f} r p10/50 {np.percentile(r,10):5.2f} {np.percentile(r,50):5.2f} open(r>.2/.3/.5) " + " ".join(f"{np.mean(r>t):.2f}" for t in (0.2,0.3,0.5))
    print(out)
