import re,glob,numpy as np
files=sorted(glob.glob('/tmp/gate/g40-*.log'))
def load(f):
    a=[(float(m.group(1)),float(m.group(2))) for m in re.finditer(r'vision (\S+) up (\S+)',open(f).read())]
    return np.array(a)
rules={'r.6':lambda r:r>=.6,'r.7':lambda r:r>=.7,'r.8':lambda r:r>=.8,
 'r.6x2':lambda r:(r>=.6)&np.r_[False,r[:-1]>=.6],'r.5x2':lambda r:(r>=.5)&np.r_[False,r[:-1]>=.5],
 'r.5x3':lambda r:(r>=.5)&np.r_[False,r[:-1]>=.5]&np.r_[False,False,r[:-2]>=.5],
 'r.6x3':lambda r:(r>=.6)&np.r_[False,r[:-1]>=.6]&np.r_[False,False,r[:-2]>=.6]}
print(f"{'':22s}"+"".join(f"{k:>9s}" for k in rules))
for f in files:
    a=load(f); r=a[:,0]/a[:,1]
    print(f"{f.split('/')[-1][4:-4]:22s}"+"".join(f"{int(v(r).sum()):4d}/{len(r):<4d}" for v in rules.values()))
