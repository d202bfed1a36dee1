"""Thread time of Tracker.track and LocalMapper.insert_keyframe (and estimate_vertical) on one cell, in process."""
import sys, time
from pathlib import Path
import numpy as np
ROOT = Path("/work/wt/attitude")
sys.path.insert(0, str(ROOT)); sys.path.insert(0, str(ROOT / "benchmarks"))
import bench_enhance_diagnose as bed
from canopy.backend import LocalMapper
from canopy.frontend import Tracker
import canopy.lines.vertical as lv
from canopy.config import parse_setting

path, clean, frames = sys.argv[1], sys.argv[2], int(sys.argv[3])
sets = [parse_setting(s) for s in sys.argv[4:]]
trk, kfs, ver = [], [], []
_orig = lv.estimate_vertical
def timed_est(*a, **k):
    t = time.thread_time(); r = _orig(*a, **k); ver.append(time.thread_time() - t); return r
lv.estimate_vertical = timed_est
class T_(Tracker):
    def track(self, *a, **k):
        t = time.thread_time(); r = super().track(*a, **k); trk.append(time.thread_time() - t); return r
class M_(LocalMapper):
    def insert_keyframe(self, kf):
        t = time.thread_time(); r = super().insert_keyframe(kf); kfs.append(time.thread_time() - t); return r
bed.Tracker, bed.LocalMapper = T_, M_
out, _ = bed.run(path, clean, "synthetic", {}, {f: v for s, f, v in sets if s == "tracking"}, frames, stereo=False,
                 kind="euroc", map_sets={f: v for s, f, v in sets if s == "mapping"})
f = lambda a: f"mean {1e3*np.mean(a):.2f} p50 {1e3*np.median(a):.2f} ms (n {len(a)})"
print(f"ATE {1e3*out['ate']:.3f} mm; track {f(trk)}; insert_keyframe {f(kfs)}; estimate_vertical {f(ver) if ver else '-'}")
