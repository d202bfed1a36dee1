import sys, os, pickle, warnings; warnings.simplefilter("ignore"); sys.path.insert(0, os.getcwd())
import numpy as np
import pyorbslam3 as pos
from canopy.sources import open_source
from benchmarks.peers.orbslam3 import settings_yaml
src = open_source("euroc", None)
text, raw = settings_yaml(src, "euroc")
open("/tmp/j/orb.yaml","w").write(text)
slam = pos.Slam("/work/cache/vocabulary/orb_k10_L5.txt", "/tmp/j/orb.yaml", pos.Sensor.STEREO)
out = []
for i in range(len(src)):
    l, r = src.raw_pair(i)
    res = slam.track_stereo(np.ascontiguousarray(l), np.ascontiguousarray(r), float(src.timestamps[i]))
    kp = slam.tracked_keypoints(); mp = slam.tracked_map_points()
    if i == 0: print(type(kp), type(mp), repr(kp)[:300], repr(mp)[:300], flush=True)
    out.append(dict(ok=(res.state == pos.TrackingState.OK), pose=np.asarray(res.pose_wc).reshape(4,4), kp=kp, mp=mp))
pickle.dump(out, open("/tmp/j/orb2.pkl","wb"))
print("done")
slam.shutdown()
os._exit(0)
