#!/usr/bin/env python
"""s13-haze: per-frame evidence on KITTI's lit hazy cells (issue 9), in process as the grid runs it.

Per frame: the frame-to-frame rotation / translation error against ground truth, the tracked
(inlier) map points and their depth in the camera (quantiles, counts beyond 20 / 30 m), the stereo
points, and ATE at the end (SE(3), the grid's number). Run:

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s13_haze/diag_frames.py \
        /work/cache/degraded/kitti-all-g1-b0.06-high-seed0 [--set tracking.name=value ...] [--out f.npz]
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
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


def rot_deg(R):
    return float(np.degrees(np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0))))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("path")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--out", default=None)
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args()
    sets = {"tracking": {}, "mapping": {}, "enhancement": {}}
    for s in a.set:
        k, v = s.split("=", 1)
        sec, f = k.split(".", 1)
        sets[sec][f] = parse_value(v)
    cfg = load_run_config("kitti")
    enh = replace(cfg.enhancement, method="auto", **sets["enhancement"])
    tp = replace(cfg.tracking, **sets["tracking"])
    src = open_source("kitti", a.path)
    gt = open_source("kitti", BUNDLED_DATA["kitti"]).ground_truth.poses
    enhancer = make_enhancer(enh)
    tracker = Tracker(src.calibration, tp)
    mapper = LocalMapper(src.calibration, replace(cfg.mapping, **sets["mapping"]))
    schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
    rel, refs, poses, stat, rows = [], [], [], [], []
    for i in range(len(src)):
        fr = src.frame(i)
        for u in schedule.take_due(fr.index):
            tracker.apply_map_update(u)
        le, re, info = enhance_pair(enhancer, fr.left, fr.right)
        kw = actor_fast(enh, info, le, tp.n_features)
        res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re), **kw)
        if res.is_keyframe and res.keyframe is not None:
            schedule.keyframe_sent(res.keyframe.index, fr.index)
            schedule.hold(mapper.insert_keyframe(res.keyframe))
        poses.append(res.T_world_cam.copy())
        rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
        refs.append(res.reference_kf_index)
        stat.append(res.status)
        X = tracker._last_matched[0]
        z = transform(se3_inv(res.T_world_cam), X)[:, 2] if len(X) else np.zeros(0)
        st = tracker._stereo_last
        sd = st.depth[st.valid] if st is not None else np.zeros(0)
        rows.append(dict(i=i, status=res.status, kf=bool(res.is_keyframe), inl=int(res.n_inliers),
                         n_lm=len(z), z50=float(np.median(z)) if len(z) else np.nan,
                         z90=float(np.percentile(z, 90)) if len(z) else np.nan,
                         far20=int((z > 20).sum()), far30=int((z > 30).sum()),
                         stereo=int(len(sd)), st_far20=int((sd > 20).sum())))
    kf = mapper.keyframe_poses()
    est = np.array([kf[r] @ T if T is not None and r in kf else P for T, r, P in zip(rel, refs, poses)])
    g = gt[: len(est)]
    for i in range(1, len(est)):
        de, dg = se3_inv(est[i - 1]) @ est[i], se3_inv(g[i - 1]) @ g[i]
        E = se3_inv(dg) @ de
        rows[i]["drot"] = rot_deg(E[:3, :3])
        rows[i]["dtrans_mm"] = 1000 * float(np.linalg.norm(E[:3, 3]))
        # heading error: yaw about camera y of the relative-motion error
        rows[i]["dyaw"] = float(np.degrees(np.arctan2(E[0, 2], E[2, 2])))
    tracked = np.array([s in ("ok", "init") for s in stat])
    ate = ape(est[tracked], g[tracked], "se3")["rmse"]
    # cumulative heading error of the absolute poses (after no alignment: both start at identity)
    yaw_abs = [float(np.degrees(np.arctan2((se3_inv(gg) @ e)[0, 2], (se3_inv(gg) @ e)[2, 2]))) for e, gg in zip(est, g)]
    for r, y in zip(rows, yaw_abs):
        r["yaw_abs"] = y
    if not a.quiet:
        for r in rows:
            print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items()))
    summ = dict(ate_mm=1000 * ate, tracked=100 * float(tracked.mean()), kf=len(kf),
                drot_med=float(np.nanmedian([r.get("drot", np.nan) for r in rows])),
                drot_rms=float(np.sqrt(np.nanmean([r.get("drot", np.nan) ** 2 for r in rows]))),
                dtrans_med=float(np.nanmedian([r.get("dtrans_mm", np.nan) for r in rows])),
                inl_med=float(np.median([r["inl"] for r in rows])), z50_med=float(np.nanmedian([r["z50"] for r in rows])),
                far20_med=float(np.median([r["far20"] for r in rows])), far30_med=float(np.median([r["far30"] for r in rows])),
                stereo_med=float(np.median([r["stereo"] for r in rows])), st_far20_med=float(np.median([r["st_far20"] for r in rows])),
                yaw_abs_end=rows[-1]["yaw_abs"])
    print("SUMMARY", Path(a.path).name, a.set, json.dumps({k: round(v, 4) for k, v in summ.items()}))
    if a.out:
        np.savez(a.out, est=est, gt=g, rows=json.dumps(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
