#!/usr/bin/env python
"""Per-frame diagnosis of a generated (or degraded) preset sequence, in process, as the grid runs it
(``bench_enhance_diagnose.run``'s loop: auto enhancement, the actors' FAST rule, tracking + local mapping).

Per frame: auto's decision, exposure gamma, the denoiser's sigma, the raw left image's robust sigma
(``estimate_noise``, rows 0.5) and that of the enhanced image, keypoints, stereo points and the share of
them > 10 % off the renderer's exact depth (``mav0/depth0``), the median |disparity error| of points on a
surface, pose inliers, local-map matches, keyframe, and the per-frame step ratio / error against the
ground truth. Prints segment medians; ``--out`` saves every row (.npz).

    PYTHONPATH=$PWD CANOPY_CACHE_DIR=/work/cache python docs/results/s14_darkrows/diag_frames.py \
        --path /work/cache/degraded/dark-rows-150-g1-b0-high-seed0 --max-frames 150 [--enh k=v] [--set k=v]
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.enhance.noise import estimate_noise  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

CLEAN = "/work/cache/synthetic/dark-rows-seed0-full"


def run(path, clean_path, max_frames, enh_sets, track_sets):
    cfg = load_run_config("synthetic")
    enh = replace(cfg.enhancement, **enh_sets)
    tp = replace(cfg.tracking, **track_sets)
    src = open_source("euroc", path, max_frames=max_frames)
    clean = open_source("euroc", clean_path, max_frames=max_frames)
    depth_files = sorted((Path(path) / "mav0" / "depth0" / "data").iterdir()) \
        if (Path(path) / "mav0" / "depth0").is_dir() else \
        sorted((Path(clean_path) / "mav0" / "depth0" / "data").iterdir())
    enhancer = make_enhancer(enh)
    tracker = Tracker(src.calibration, tp)
    mapper = LocalMapper(src.calibration, cfg.mapping)
    schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
    cap = {}
    orig_ls, orig_st = tracker._left_and_stereo, tracker._stereo

    def ls(*a, **k):
        out = orig_ls(*a, **k)
        cap["left"] = out[0]
        return out

    def st(*a, **k):
        out = orig_st(*a, **k)
        cap["stereo"] = out
        return out
    tracker._left_and_stereo, tracker._stereo = ls, st
    fb = src.calibration.fx * src.calibration.baseline
    rows, poses, rel, refs, statuses = [], [], [], [], []
    for i in range(len(src)):
        fr = src.frame(i)
        for update in schedule.take_due(fr.index):
            tracker.apply_map_update(update)
        le, re, info = enhance_pair(enhancer, fr.left, fr.right)
        kw = actor_fast(enh, info, le, tp.n_features)
        res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re), **kw)
        left, stereo = cap["left"], cap["stereo"]
        idx = np.flatnonzero(stereo.valid)
        exact = cv2.imread(str(depth_files[i]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        h, w = exact.shape
        uv = left.uv[idx]
        x = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
        y = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
        zt = exact[y, x]
        z = stereo.depth[idx]
        off = (zt <= 0) | (np.abs(z / np.maximum(zt, 1e-6) - 1) > 0.10)
        lo = cv2.erode(exact, np.ones((5, 5), np.uint8))[y, x]
        hi = cv2.dilate(exact, np.ones((5, 5), np.uint8))[y, x]
        surf = (lo > 0) & (hi < 1.05 * lo)
        dsig = fb / z[surf] - fb / zt[surf] if surf.any() else np.array([np.nan])
        derr = np.abs(dsig)
        near_ok = np.abs(dsig) <= 1.0  # the signed bias of the points within 1 px (outliers aside)
        rows.append(dict(i=i, method=info["method"], gamma=info.get("gamma", 1.0), dn_sigma=info["noise_sigma"],
                         raw_sigma=estimate_noise(fr.left, rows_fraction=0.5),
                         enh_sigma=estimate_noise(le, rows_fraction=0.5), mean_raw=float(fr.left.mean()),
                         mean_enh=float(le.mean()), thr=kw.get("fast_threshold") or -1,
                         thr_fb=kw.get("fast_fallback") or -1, kp=len(left.uv), stereo=len(idx),
                         off10=float(off.mean()) if len(idx) else np.nan, d_err=float(np.median(derr)),
                         d_bad=float(np.mean(derr > 1.0)),
                         d_bias=float(np.mean(dsig[near_ok])) if near_ok.any() else np.nan,
                         d_rel_pct=float(100 * np.mean(dsig[near_ok] / (fb / zt[surf][near_ok]))) if near_ok.any() else np.nan, inl=int(res.n_inliers), matches=int(res.n_matches),
                         kf=int(bool(res.is_keyframe)), status=res.status))
        if res.is_keyframe and res.keyframe is not None:
            schedule.keyframe_sent(res.keyframe.index, fr.index)
            schedule.hold(mapper.insert_keyframe(res.keyframe))
        poses.append(res.T_world_cam.copy())
        rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
        refs.append(res.reference_kf_index)
        statuses.append(res.status)
    kf = mapper.keyframe_poses()
    est = np.array([kf[r] @ T if T is not None and r in kf else P for T, r, P in zip(rel, refs, poses)])
    gt = clean.ground_truth.poses[: len(est)]
    a = ape(est, gt, "se3")
    for i in range(1, len(est)):
        de, dg = se3_inv(est[i - 1]) @ est[i], se3_inv(gt[i - 1]) @ gt[i]
        tg = np.linalg.norm(dg[:3, 3])
        rows[i]["step_gt_mm"] = 1000 * tg
        rows[i]["ratio"] = float(np.linalg.norm(de[:3, 3]) / tg) if tg > 0.002 else np.nan
        rows[i]["dt_err_mm"] = 1000 * float(np.linalg.norm(de[:3, 3] - dg[:3, 3]))
        r = cv2.Rodrigues(np.ascontiguousarray(dg[:3, :3].T @ de[:3, :3]))[0].ravel()
        rows[i]["drot_deg"] = float(np.degrees(np.linalg.norm(r)))
    return a["rmse"], rows, est, gt


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--path", required=True)
    ap.add_argument("--clean", default=CLEAN)
    ap.add_argument("--max-frames", type=int, default=150)
    ap.add_argument("--enh", action="append", default=[])
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--segments", type=int, default=6)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    enh = {k: parse_value(v) for k, v in (s.split("=", 1) for s in args.enh)}
    trk = {k: parse_value(v) for k, v in (s.split("=", 1) for s in args.set)}
    ate, rows, est, gt = run(args.path, args.clean, args.max_frames, enh, trk)
    dec = {}
    for r in rows:
        dec[r["method"]] = dec.get(r["method"], 0) + 1
    print(f"ATE {1000 * ate:.3f} mm  decisions {dec}  keyframes {sum(r['kf'] for r in rows)}")
    keys = ["gamma", "dn_sigma", "raw_sigma", "enh_sigma", "mean_raw", "mean_enh", "thr", "thr_fb", "kp", "stereo",
            "off10", "d_err", "d_bad", "d_bias", "d_rel_pct", "inl", "matches", "ratio", "dt_err_mm", "drot_deg"]
    print("frames  " + " ".join(f"{k:>9s}" for k in keys) + "  kfs")
    n = len(rows)
    for s in range(args.segments):
        seg = rows[s * n // args.segments:(s + 1) * n // args.segments]
        med = [np.nanmedian([r.get(k, np.nan) for r in seg]) for k in keys]
        print(f"{seg[0]['i']:3d}-{seg[-1]['i']:3d} " + " ".join(f"{v:9.3f}" for v in med) + f"  {sum(r['kf'] for r in seg)}")
    med = [np.nanmedian([r.get(k, np.nan) for r in rows]) for k in keys]
    print("all     " + " ".join(f"{v:9.3f}" for v in med))
    err = est[:, :3, 3] - gt[:, :3, 3]
    if args.out:
        np.savez(args.out, rows=np.array(rows, dtype=object), est=est, gt=gt)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
