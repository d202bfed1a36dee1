"""s10-keyframes diagnostic: per frame, the keyframe counts (frames since keyframe, entropy ratio, n_ref,
ref first, tracked close, untracked close, reasons). Usage: PYTHONPATH=$PWD python <this> kitti 0 ["name:section.key=value"]"""
import sys, numpy as np
sys.path.insert(0, '.')
import canopy.frontend.tracker as T
import benchmarks.profile_tracking as PT
from canopy.config import parse_variant
from canopy.sources import open_source
from canopy.metrics import ape
log = []
orig = T.keyframe_reasons
def kr(p, since, ratio, n_ref, first, ntc, nnc):
    out = orig(p, since, ratio, n_ref, first, ntc, nnc)
    log.append((since, ratio, n_ref, first, ntc, nnc, "+".join(out)))
    return out
T.keyframe_reasons = kr
ds = sys.argv[1]
src = open_source(ds, None, max_frames=int(sys.argv[2]) if len(sys.argv) > 2 and sys.argv[2] != '0' else None)
frames = [src.frame(i) for i in range(len(src))]
sets = parse_variant(sys.argv[3])[1] if len(sys.argv) > 3 else []
r = PT.run_once(ds, frames, src.calibration, sets)
gt = src.ground_truth.poses[:len(frames)]
print("kf", r["keyframes"], "ATE", ape(r["est"], gt, align="se3")["rmse"], r["keyframe_reasons"])
for i, l in enumerate(log):
    print(i + 1, *[("%.2f" % x if isinstance(x, float) else x) for x in l])
