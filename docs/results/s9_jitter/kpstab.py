import sys, os, pickle, warnings; warnings.simplefilter("ignore"); sys.path.insert(0, os.getcwd())
import numpy as np
from scipy.spatial import cKDTree
from canopy.sources import open_source
from canopy.frontend.features import OrbExtractor
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.params import TrackingParams
def stab(kps):
    r=[]
    for a,b in zip(kps[:-1],kps[1:]):
        d,_=cKDTree(b).query(a); r.append(d)
    d=np.concatenate(r)
    return "n/frame %d; nearest in next frame: 0 px %.3f, <=1.5 px %.3f, <=3 px %.3f, >3 %.3f" % (np.mean([len(k) for k in kps]), (d<1e-3).mean(), ((d>1e-3)&(d<=1.5)).mean(), ((d>1.5)&(d<=3)).mean(), (d>3).mean())
d = pickle.load(open("/tmp/j/orb2.pkl","rb"))
print("ORB-SLAM3 keypoints:", stab([x['kp'] for x in d]))
pose=np.array([x['pose'] for x in d]); c=pose[:,:3,3]
print("ORB-SLAM3 this run: frame-diff of camera centre rms %.3f mm, tracked map points med %d" % (np.sqrt((np.diff(c,axis=0)**2).sum(1).mean())*1e3, np.median([len(x['mp']) for x in d])))
src = open_source("euroc", None)
for name, ex in (("canopy opencv 1000", OrbExtractor(TrackingParams())), ("canopy cells 1200", CellExtractor(TrackingParams(n_features=1200, extractor="cells")))):
    kps=[ex.extract(src.frame(i).left).uv.astype(float) for i in range(len(src))]
    print(name, stab(kps))
