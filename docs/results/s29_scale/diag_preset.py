"""One preset cell in process; prints ATE, Sim3, scale and the drift of the attitude (world-frame rotation
vector of est vs gt, first-pose aligned) at a few frames. usage: diag_preset.py PATH [track k=v ...] [map:k=v]"""
import json, sys
import numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[3]))
import benchmarks.bench_enhance_diagnose as bed
from canopy.config import parse_value
import cv2
path = sys.argv[1]; preset = path.split("/")[-1].split("-300")[0]
ts, ms = {}, {}
for a in sys.argv[2:]:
    k, v = a.split("=", 1)
    (ms if k.startswith("map:") else ts)[k.split(":")[-1]] = parse_value(v)
cache = __import__("os").environ.get("CANOPY_CACHE_DIR", "/work/cache")
clean = f"{cache}/synthetic/{preset}-seed0-full"
_keep = {}
_orig = bed.TrajectoryRecorder.trajectory
def _traj(self, mapper):
    r = _orig(self, mapper); _keep["est"] = r; return r
bed.TrajectoryRecorder.trajectory = _traj
out, rows = bed.run(path, clean, "synthetic", {}, ts, max_frames=300, stereo=False, kind="euroc", map_sets=ms)
print(json.dumps({k: round(out[k], 5) for k in ("tracked", "ate", "ate_sim3", "scale") if k in out}))

from canopy.sources import open_source
est, tr = _keep["est"]
gt = open_source("euroc", clean, max_frames=300).ground_truth.poses[:len(est)]
# first-pose alignment: A = gt0 est0^-1
A = gt[0] @ np.linalg.inv(est[0])
for i in (50, 100, 150, 200, 250, len(est) - 1):
    Re = (A @ est[i])[:3, :3]; Rg = gt[i][:3, :3]
    rv = cv2.Rodrigues(Rg @ Re.T)[0].ravel()  # world-frame rotation error
    te = (A @ est[i])[:3, 3] - gt[i][:3, 3]
    print(f"f{i:3d} rot_err_deg(world xyz) {np.degrees(rv).round(3)}  pos_err_m {te.round(3)}")
