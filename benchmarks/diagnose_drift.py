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

``--oracle-depth`` (generated sequences only: needs the generator's exact depth, ``mav0/depth0``):
a diagnosis, not a method. Every stereo point whose stereo depth is more than ``--oracle-tol``
(10 %) off the exact depth at its pixel, or that sits on sky, is measured bearing-only and makes
no landmark: the handling of ``tracking.contour_enabled`` with a perfect detector in place of
StereoBM (dropping the stereo match instead gives the same trajectory: the keypoint is then a
monocular observation all the same). It says how much of the drift the wrong stereo depths
cause, and what a perfect occluding-contour test could gain.
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
from canopy.metrics import align_trajectory, ape  # noqa: E402
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


def exact_depth_loader(path):
    """Frame index -> the generator's exact depth (m, 0 = sky) of a generated sequence."""
    import cv2
    folder = Path(path) / "mav0" / "depth0" / "data"
    if not folder.is_dir():
        raise SystemExit(f"--oracle-depth needs the generator's exact depth: {folder} does not exist")
    files = sorted(folder.iterdir())
    return lambda i: cv2.imread(str(files[i]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0


def wrong_depth(depth_map: np.ndarray, uv: np.ndarray, stereo_depth: np.ndarray, tol: float) -> np.ndarray:
    """True where a stereo depth is more than ``tol`` (relative) off the exact depth at the
    keypoint's pixel, or where that pixel is sky."""
    h, w = depth_map.shape
    x = np.clip(np.round(uv[:, 0]).astype(np.int64), 0, w - 1)
    y = np.clip(np.round(uv[:, 1]).astype(np.int64), 0, h - 1)
    z = depth_map[y, x]
    return (z <= 0) | (np.abs(stereo_depth / np.maximum(z, 1e-6) - 1.0) > tol)


def oracle_tracker(calib, tp, path, tol: float):
    """A Tracker whose occluding-contour flags come from the exact depth (see the docstring)."""
    from dataclasses import replace
    from canopy.frontend.stereo import StereoMatches

    exact = exact_depth_loader(path)

    class OracleTracker(Tracker):
        def track(self, frame, *a, **k):
            self._oracle_depth = exact(frame.index)
            return super().track(frame, *a, **k)

        def _flag_contours(self, left_img, right_img, feats, stereo):
            v = np.flatnonzero(stereo.valid)
            bad = np.zeros(len(stereo.depth), bool)
            bad[v] = wrong_depth(self._oracle_depth, feats.uv[v], stereo.depth[v], tol)
            return StereoMatches(stereo.u_right, stereo.depth, stereo.n_candidates, on_contour=bad)

    # contour_enabled routes every frame's matches through _flag_contours
    return OracleTracker(calib, replace(tp, contour_enabled=True))


def run(dataset, path, max_frames, sets, oracle=False, oracle_tol=0.10):
    cfg = with_settings(load_run_config(dataset), [parse_setting(s) for s in sets])
    tp, mp = cfg.tracking, cfg.mapping
    src = open_source("euroc" if dataset == "synthetic" else dataset, path, max_frames=max_frames)
    calib = src.calibration
    tracker = oracle_tracker(calib, tp, path, oracle_tol) if oracle else Tracker(calib, tp)
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
    # which way the positions are off (world axes; generated sequences: z is up, the rows run along x)
    err = align_trajectory(final, gt, with_scale=False)[:, :3, 3] - gt[:, :3, 3]
    rms = np.sqrt((err ** 2).mean(axis=0))
    print(f"ATE per world axis (rms, m): x {rms[0]:.4f}  y {rms[1]:.4f}  z {rms[2]:.4f}")
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
    ap.add_argument("--oracle-depth", action="store_true",
                    help="generated sequences: stereo points with a wrong depth (vs the exact depth) bearing-only")
    ap.add_argument("--oracle-tol", type=float, default=0.10, help="relative depth error counted as wrong")
    args = ap.parse_args()
    d = run(args.dataset, args.path, args.max_frames, args.set, args.oracle_depth, args.oracle_tol)
    summarise(d, args.segments)
    if args.out:
        np.savez(args.out, **d)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
