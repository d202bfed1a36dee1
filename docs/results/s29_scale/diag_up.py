"""Per keyframe: the measured up against the generator's exact up (angle error / sigma), and the gate's verdict."""
import sys, numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[3]))
import benchmarks.bench_enhance_diagnose as bed
import canopy.frontend.tracker_vertical as tv
import canopy.frontend.tracker_segments as ts
from canopy.config import parse_value
from canopy.sources import open_source
path = sys.argv[1]; preset = path.split("/")[-1].split("-300")[0].split("-150")[0]
sets = {k: parse_value(v) for k, v in (a.split("=", 1) for a in sys.argv[2:])}
cache = __import__("os").environ.get("CANOPY_CACHE_DIR", "/work/cache")
clean = f"{cache}/synthetic/{preset}-seed0-full"
gt = open_source("euroc", clean, max_frames=300).ground_truth.poses
log = []
_m = tv.KeyframeVertical.measure
def measure(self, image, T, index=-1):
    up, s = _m(self, image, T, index); log.append([index, up, s, None]); return up, s
tv.KeyframeVertical.measure = measure
_g = ts.gate_keyframe_up
def gate(*a, **k):
    r = _g(*a, **k)
    if log: log[-1][3] = bool(np.isfinite(r[1]))
    return r
ts.gate_keyframe_up = gate
n = 300 if "day" in preset or "haze" in preset else 150
out, rows = bed.run(path, clean, "synthetic", {}, sets, max_frames=n, stereo=False, kind="euroc")
print(out.get("ate"), out.get("tracked"))
errs = []
for idx, up, s, opened in log:
    if not np.isfinite(s): continue
    tu = gt[idx][:3, :3].T @ np.array([0, 0, 1.0])
    e = np.degrees(np.arccos(np.clip(up @ tu, -1, 1)))
    errs.append((idx, e, s, opened))
a = np.array([(e, s, o) for _, e, s, o in errs], float)
print("measured", len(a), "of", len(log), "keyframes; sent", int(a[:, 2].sum()))
for lab, m in (("all", np.ones(len(a), bool)), ("sent", a[:, 2] > 0)):
    if m.sum():
        print(f"{lab}: err p50 {np.median(a[m,0]):.3f} deg  sigma p50 {np.median(a[m,1]):.3f}  err/sigma rms {np.sqrt(np.mean((a[m,0]/a[m,1])**2)):.2f}  p90 err {np.percentile(a[m,0],90):.3f}")
print("signed error of the sent ups (deg): roll-like (camera x) / pitch-like (camera z), per 10 keyframes")
rows_ = []
for idx, up, s, opened in log:
    if not np.isfinite(s) or not opened: continue
    tu = gt[idx][:3, :3].T @ np.array([0, 0, 1.0])
    d = np.degrees(up - tu)
    rows_.append((idx, d[0], d[2]))
r = np.array(rows_)
for k in range(0, len(r), 10):
    c = r[k:k+10]
    print(f"  kf {int(c[0,0]):3d}-{int(c[-1,0]):3d}  x {c[:,1].mean():+.3f}  z {c[:,2].mean():+.3f}")
