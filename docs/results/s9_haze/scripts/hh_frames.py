"""Canopy on one KITTI cell, in process as bench_degrade_grid runs it (bench_enhance_diagnose's loop):
per frame the tracker's own pose error (dt_err of the pose as tracked) beside the final one (after
local BA, as the ATE sees it), the keyframes, and for the frames given the depth of the stage-2 pose
inliers (near points fix the translation, far ones only the rotation).

    python docs/results/s9_haze/scripts/hh_frames.py /work/cache/degraded/kitti-all-g1-b0.06-high-seed0 31 32 33 [--set name=value ...]
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[4]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv, transform  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

path = sys.argv[1]
args = sys.argv[2:]
sets = {}
if "--set" in args:
    k = args.index("--set")
    sets = {a.split("=", 1)[0]: parse_value(a.split("=", 1)[1]) for a in args[k + 1:]}
    args = args[:k]
watch = {int(a) for a in args}
cfg = load_run_config("kitti")
tp = replace(cfg.tracking, **sets)
src, clean = open_source("kitti", path), open_source("kitti", BUNDLED_DATA["kitti"])
enhancer = make_enhancer(cfg.enhancement)
tracker = Tracker(src.calibration, tp)
mapper = LocalMapper(src.calibration, cfg.mapping)
schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
captured = {}
orig_refine = Tracker._refine


def refine(self, T, X, r, feats, stereo, **kw):
    est = orig_refine(self, T, X, r, feats, stereo, **kw)
    if self._watch:
        z = transform(est.T_cam_world, X)[:, 2]
        captured.setdefault(self._cur, []).append((len(X), z[est.inliers]))
    return est


Tracker._refine = refine
raw, rel, refs, kfs = [], [], [], []
for i in range(len(src)):
    fr = src.frame(i)
    for u in schedule.take_due(fr.index):
        tracker.apply_map_update(u)
    le, re_, info = enhance_pair(enhancer, fr.left, fr.right)
    kw = actor_fast(cfg.enhancement, info, le, tp.n_features, "actor")
    tracker._watch, tracker._cur = i in watch, i
    res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re_), **kw)
    if res.is_keyframe and res.keyframe is not None:
        schedule.keyframe_sent(res.keyframe.index, fr.index)
        schedule.hold(mapper.insert_keyframe(res.keyframe))
        kfs.append((i, res.keyframe_reason))
    raw.append(res.T_world_cam.copy())
    rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
    refs.append(res.reference_kf_index)
kf = mapper.keyframe_poses()
final = np.array([kf[r] @ T if T is not None and r in kf else P for T, r, P in zip(rel, refs, raw)])
gt = clean.ground_truth.poses[: len(final)]
print("ATE final", ape(final, gt, "se3")["rmse"], " ATE as tracked", ape(np.array(raw), gt, "se3")["rmse"])
print("keyframes", kfs)
for i in range(1, len(gt)):
    dg = se3_inv(gt[i - 1]) @ gt[i]
    e = [np.linalg.norm((se3_inv(P[i - 1]) @ P[i])[:3, 3] - dg[:3, 3]) for P in (raw, final)]
    flag = " <" if max(e) > 0.05 else ""
    print(f"{i}: dt_err tracked {e[0]:.3f} final {e[1]:.3f}{flag}")
for i in sorted(captured):
    for n, z in captured[i]:
        print(f"frame {i}: refine on {n} points, {len(z)} inliers; depth of inliers: "
              f"< 10 m {np.sum(z < 10)}, 10-20 m {np.sum((z >= 10) & (z < 20))}, >= 20 m {np.sum(z >= 20)}, "
              f"median {np.median(z):.1f} m")
