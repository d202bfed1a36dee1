#!/usr/bin/env python
"""Where does drift come from? Frame by frame against ground truth, in-process lockstep.

Runs the tracking -> local mapping loop of ``canopy.pipeline.run_sequential`` with a dataset's
shipped config and records, per frame, the tracked pose (online, before any later BA), inliers,
tracked close / far points and keyframes; per keyframe, the local BA window (local and fixed
keyframes), the landmarks it creates and how many of the previous keyframe's landmarks it still
sees. Writes everything to an ``.npz`` and prints a per-segment table: rotation error picked up
per frame, split about the camera's x (pitch), y (yaw) and z (roll) axes.

    PYTHONPATH=$PWD CANOPY_CACHE_DIR=/work/cache python benchmarks/diagnose_drift.py \
        --path /work/cache/synthetic/day-loop-seed0-full --out /tmp/drift_base.npz [--set tracking.x=1]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config, parse_setting, with_settings  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.metrics import ape  # noqa: E402
from canopy.pipeline import frame_poses  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of a 3x3 rotation."""
    import cv2
    return cv2.Rodrigues(np.ascontiguousarray(R))[0].reshape(3)


def relative_rotation_errors(est: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(N-1, 3) per-frame rotation error of the relative motion, rotation vector (deg) in the
    camera frame of the earlier frame: x pitch, y yaw, z roll."""
    out = np.zeros((len(est) - 1, 3))
    for i in range(1, len(est)):
        de = se3_inv(est[i - 1]) @ est[i]
        dg = se3_inv(gt[i - 1]) @ gt[i]
        out[i - 1] = np.degrees(rotvec(dg[:3, :3].T @ de[:3, :3]))
    return out


def run(dataset, path, max_frames, sets):
    cfg = with_settings(load_run_config(dataset), [parse_setting(s) for s in sets])
    tp, mp = cfg.tracking, cfg.mapping
    src = open_source("euroc" if dataset == "synthetic" else dataset, path, max_frames=max_frames)
    calib = src.calibration
    tracker = Tracker(calib, tp)
    mapper = LocalMapper(calib, mp)
    n = len(src) if max_frames is None else min(len(src), max_frames)
    rec = {k: [] for k in ("online", "n_inl", "n_match", "is_kf", "status")}
    refs, rel, statuses, track_poses, stamps = [], [], [], [], []
    kf_rows = []
    t0 = time.perf_counter()
    for i in range(n):
        frame = src.frame(i)
        res = tracker.track(frame)
        stamps.append(frame.timestamp)
        rec["online"].append(res.T_world_cam.copy())
        rec["n_inl"].append(res.n_inliers)
        rec["n_match"].append(res.n_matches)
        rec["is_kf"].append(bool(res.is_keyframe))
        statuses.append(res.status)
        track_poses.append(res.T_world_cam.copy())
        if res.is_keyframe and res.keyframe is not None:
            kf = res.keyframe
            upd = mapper.insert_keyframe(kf)
            tracker.apply_map_update(upd)
            local, fixed = getattr(mapper, "last_window", ([], []))
            depth = kf.depth[kf.landmark_ids >= 0]
            kf_rows.append((i, len(local), len(fixed), int((kf.landmark_ids >= 0).sum()),
                            int((kf.new_landmark_ids >= 0).sum()), float(np.median(depth)) if len(depth) else 0.0,
                            len(upd.landmark_ids), min(local) if local else -1, min(fixed) if fixed else -1))
        refs.append(res.reference_kf_index)
        rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
    wall = time.perf_counter() - t0
    poses = np.asarray(frame_poses(mapper.keyframe_poses(), refs, rel, track_poses, statuses))
    gt = src.ground_truth.poses[:n]
    return dict(final=poses, gt=gt, online=np.asarray(rec["online"]), n_inl=np.asarray(rec["n_inl"]),
                n_match=np.asarray(rec["n_match"]), is_kf=np.asarray(rec["is_kf"]),
                kf=np.asarray(kf_rows, float).reshape(-1, 9), wall=wall)


def summarise(d: dict, segments: int = 10) -> None:
    final, gt, online = d["final"], d["gt"], d["online"]
    a = ape(final, gt, align="se3")["rmse"]
    print(f"ATE {a:.4f} m  keyframes {int(d['is_kf'].sum())}/{len(final)}  wall {d['wall']:.0f} s")
    for name, est in (("online", online), ("final", final)):
        err = relative_rotation_errors(est, gt)
        gt_rot = np.degrees(np.array([np.linalg.norm(rotvec((se3_inv(gt[i - 1]) @ gt[i])[:3, :3]))
                                      for i in range(1, len(gt))]))
        print(f"-- {name}: rotation error summed per segment (deg, camera axes) and GT turn")
        edges = np.linspace(0, len(err), segments + 1).astype(int)
        for s, e in zip(edges[:-1], edges[1:]):
            kfs = int(d["is_kf"][s + 1:e + 1].sum())
            print(f"  frames {s:4d}-{e:4d}  err x {err[s:e, 0].sum():+.3f} y {err[s:e, 1].sum():+.3f} "
                  f"z {err[s:e, 2].sum():+.3f}  turn {gt_rot[s:e].sum():6.1f}  kf {kfs:3d}  "
                  f"inl p50 {np.median(d['n_inl'][s + 1:e + 1]):.0f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="synthetic")
    ap.add_argument("--path", default=None)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--set", action="append", default=[], help="section.name=value parameter override")
    ap.add_argument("--out", default=None, help=".npz with every per-frame and per-keyframe record")
    ap.add_argument("--segments", type=int, default=10)
    args = ap.parse_args()
    d = run(args.dataset, args.path, args.max_frames, args.set)
    summarise(d, args.segments)
    if args.out:
        np.savez(args.out, **d)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
