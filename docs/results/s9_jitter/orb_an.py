import sys, os, pickle, warnings; warnings.simplefilter("ignore"); sys.path.insert(0, os.getcwd())
import numpy as np
from canopy.sources import open_source
from canopy.metrics import ape, align_trajectory, associate
d = pickle.load(open("/tmp/j/orb_traj.pkl","rb"))
src = open_source("euroc", None)
gt = src.ground_truth.poses[:len(d["poses"])]
def an(name, est):
    al = align_trajectory(est, gt, with_scale=False); e = al[:,:3,3]-gt[:,:3,3]
    ec = np.einsum('nji,nj->ni', gt[:,:3,:3], e)
    hp = e[1:]-e[:-1]
    # smooth part: 5-frame moving average
    k=9; sm = np.array([e[max(0,i-k//2):i+k//2+1].mean(0) for i in range(len(e))])
    print(name, "ATE %.3f mm; per cam axis %s; frame-diff rms %.3f; 9-frame smooth part %.3f, residual %.3f" % (
        ape(est, gt, align="se3")['rmse']*1e3, np.round(np.sqrt((ec**2).mean(0))*1e3,3), np.sqrt((hp**2).sum(1).mean())*1e3,
        np.sqrt((sm**2).sum(1).mean())*1e3, np.sqrt(((e-sm)**2).sum(1).mean())*1e3))
print(len(d["poses"]), "stamps match", np.allclose(d["stamps"], src.timestamps[:len(d["poses"])]))
an("orb", np.asarray(d["poses"]))
if len(sys.argv)>1:
    import subprocess
