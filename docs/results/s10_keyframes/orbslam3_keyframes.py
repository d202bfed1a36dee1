"""Count the keyframes ORB-SLAM3 creates on KITTI 06 (union of keyframe stamps seen after each frame)
vs the ones its saved keyframe trajectory keeps (culled keyframes are skipped by SaveKeyFrameTrajectoryTUM)."""
import sys, time, os
from pathlib import Path
import numpy as np
sys.path.insert(0, '.')
import pyorbslam3 as pos
from benchmarks.peers.orbslam3 import settings_yaml, peer_vocabulary
from canopy.sources import open_source
sleep = float(sys.argv[1]) if len(sys.argv) > 1 else 0.3
work = Path('/tmp/s10_keyframes_orb'); work.mkdir(parents=True, exist_ok=True)
src = open_source('kitti', None)
text, raw = settings_yaml(src, 'kitti')
(work / 's.yaml').write_text(text)
slam = pos.Slam(str(peer_vocabulary(progress=False)), str(work / 's.yaml'), pos.Sensor.STEREO)
seen = set(); counts = []; ntp = []
for i in range(len(src)):
    l, r = src.raw_pair(i) if raw else (lambda f: (f.left, f.right))(src.frame(i))
    res = slam.track_stereo(np.ascontiguousarray(l), np.ascontiguousarray(r), float(src.timestamps[i])); ntp.append(res.num_tracked_points)
    time.sleep(sleep)
    f = work / 'kf.tum'
    slam.save_keyframe_trajectory_tum(str(f))
    rows = np.loadtxt(f, ndmin=2)
    st = set(np.round(rows[:, 0], 6).tolist()) if len(rows) else set()
    seen |= st; counts.append(len(st))
print("tracked points per frame", ntp, "median", np.median(ntp[2:]), "new kf frames", [i for i in range(1, len(counts)) if counts[i] > counts[i-1]]); print("frames", len(src), "keyframes ever seen", len(seen), "kept at end", counts[-1], "max kept", max(counts), flush=True)
os._exit(0)
