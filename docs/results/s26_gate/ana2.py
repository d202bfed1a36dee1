import re,glob,numpy as np,sys
pat=sys.argv[1] if len(sys.argv)>1 else 'sig2'
for D,ts in ((40,(0.4,0.5,0.6,0.7,0.8)),(70,(0.8,1.0,1.2,1.5)),(90,(1.0,1.5,2.0))):
  print("D",D)
  for f in sorted(glob.glob(f'/tmp/gate/{pat}-*.log')):
    rows=[]
    for l in open(f):
        if not l.startswith('VGATE'): continue
        t=l.split(); d=dict(zip(t[1::2],t[2::2]))
        m=dict((int(a),(float(b),float(c))) for a,b,c in re.findall(r'far(\d+) (\d+) (\d\S*|inf)\b',l.split('open')[1]))
        rows.append((float(d['up']),)+m[D])
    a=np.array(rows); r=a[:,2]/a[:,0]
    print(f"  {f.split('/')[-1][len(pat)+1:-4]:14s} r p5/10/90/max {np.percentile(r,5):5.2f} {np.percentile(r,10):5.2f} {np.percentile(r,90):5.2f} {r.max():5.2f} open " + " ".join(f">{t}:{np.mean(r>=t):.2f}" for t in ts))
