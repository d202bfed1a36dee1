import sys, os, pickle, warnings; warnings.simplefilter("ignore"); sys.path.insert(0, os.getcwd())
import numpy as np
from benchmarks.peers.orbslam3 import run_stereo
r = run_stereo(None, "euroc", pace=False)
pickle.dump({"stamps": r.trajectory.stamps, "poses": r.trajectory.poses}, open("/tmp/j/orb_traj.pkl", "wb"))
print("done", len(r.trajectory.poses))
