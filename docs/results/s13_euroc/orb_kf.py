"""ORB-SLAM3 (stereo, raw frames, as the grid's peer column) on one EuRoC cell: keyframes made and map points
tracked per frame. CELL=g1-b0.06-low python docs/results/s13_euroc/orb_kf.py  (docs/notes/s13-euroc.md)"""
import os, sys, warnings
warnings.simplefilter("ignore"); sys.path.insert(0, os.getcwd())
import numpy as np
import pyorbslam3 as pos
from canopy.sources import open_source, BUNDLED_DATA
from benchmarks.peers.orbslam3 import settings_yaml
cell = os.environ.get("CELL", "g1-b0.06-low")
path = BUNDLED_DATA["euroc"] if cell == "clean" else f"/work/cache/degraded/euroc-all-{cell}-seed{os.environ.get('SEED', '0')}"
src = open_source("euroc", path)
text, raw = settings_yaml(src, "euroc")
os.makedirs("/tmp/s13eu", exist_ok=True)
open(f"/tmp/s13eu/orb_{cell}.yaml", "w").write(text)
slam = pos.Slam("/work/cache/vocabulary/orb_k10_L5.txt", f"/tmp/s13eu/orb_{cell}.yaml", pos.Sensor.STEREO)
n = []
for i in range(len(src)):
    l, r = src.raw_pair(i)
    res = slam.track_stereo(np.ascontiguousarray(l), np.ascontiguousarray(r), float(src.timestamps[i]))
    n.append(res.num_tracked_points)
slam.save_keyframe_trajectory_tum(f"/tmp/s13eu/orb_kf_{cell}.txt")
kf = np.loadtxt(f"/tmp/s13eu/orb_kf_{cell}.txt", ndmin=2)
ts = np.asarray(src.timestamps)
idx = [int(np.argmin(np.abs(ts - t))) for t in kf[:, 0]]
print(f"ORBSLAM3 {cell}: keyframes {len(kf)} at frames {idx}; tracked map points per frame med {np.median(n):.0f} "
      f"(5-95 % {np.quantile(n, .05):.0f}-{np.quantile(n, .95):.0f})", flush=True)
slam.shutdown()
os._exit(0)
