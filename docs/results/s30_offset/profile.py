"""s30: is the rig's disparity offset observable from the run's own map (no ground truth)?

Runs tracking -> local mapping in process (as benchmarks/diagnose_drift.py), then takes the whole final map
(every keyframe, landmark and observation), fixes the inlier set by one full BA at the shipped offset, and
re-runs the full BA (first keyframe fixed, numpy Schur solver of canopy.backend.stereo_ba) with every stereo
observation's u_right shifted by -delta (d_true = d_meas + offset: delta > 0 is a larger offset). Prints, per
delta, the robust cost at convergence (the GT-free profile) and, for reading only, the keyframe trajectory's
Sim(3) scale against the ground truth and its SE(3) ATE.

    python docs/results/s30_offset/profile.py [--path CELL] [--deltas -0.2 -0.1 0 0.1 0.2]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.backend import LocalMapper  # noqa: E402
from canopy.backend.stereo_ba import StereoEdges, bundle_adjust_points, edge_chi2, _robust_cost, _project  # noqa: E402
from canopy.config import load_run_config, parse_setting, with_settings  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.metrics import umeyama_alignment  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def run_map(dataset, path, max_frames, sets):
    cfg = with_settings(load_run_config(dataset), [parse_setting(s) for s in sets])
    src = open_source("euroc" if dataset == "synthetic" else dataset, path, max_frames=max_frames)
    tracker, mapper = Tracker(src.calibration, cfg.tracking), LocalMapper(src.calibration, cfg.mapping)
    n = len(src) if max_frames is None else min(len(src), max_frames)
    for i in range(n):
        res = tracker.track(src.frame(i))
        if res.is_keyframe and res.keyframe is not None:
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
    return src, mapper, cfg


def map_edges(mapper):
    kf_ids = sorted(mapper.keyframes)
    pose_of = {k: i for i, k in enumerate(kf_ids)}
    lm_ids = sorted(mapper.landmarks)
    e_pose, e_pt, meas, octv = [], [], [], []
    for j, lid in enumerate(lm_ids):
        for k, kp in mapper.landmarks[lid].obs.items():
            if k not in pose_of:
                continue
            kf = mapper.keyframes[k]
            e_pose.append(pose_of[k]); e_pt.append(j)
            meas.append((kf.uv[kp, 0], kf.uv[kp, 1], kf.u_right[kp])); octv.append(kf.octave[kp])
    meas = np.asarray(meas, float)
    stereo = meas[:, 2] >= 0
    meas[~stereo, 2] = 0.0
    X = np.stack([mapper.landmarks[l].position for l in lm_ids])
    return kf_ids, np.asarray(e_pose), np.asarray(e_pt), meas, stereo, np.asarray(octv, float), X


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--path", default=None)
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--deltas", type=float, nargs="+", default=[-0.3, -0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, 0.3])
    ap.add_argument("--iterations", type=int, default=30)
    a = ap.parse_args()
    src, mapper, cfg = run_map(a.dataset, a.path, a.max_frames, a.set)
    mp, calib = cfg.mapping, src.calibration
    kf_ids, e_pose, e_pt, meas, stereo, octv, X0 = map_edges(mapper)
    # the first keyframe fixed: it goes last (stereo_ba: local poses first)
    order = kf_ids[1:] + kf_ids[:1]
    perm = {k: i for i, k in enumerate(order)}
    e_pose = np.asarray([perm[kf_ids[p]] for p in e_pose])
    T0 = np.stack([se3_inv(mapper.keyframes[k].T_world_cam) for k in order])
    scale = cfg.tracking.scale_factor
    sigma = mp.pixel_sigma * scale ** octv
    huber = np.where(stereo, mp.huber_stereo, mp.huber_mono)
    thr = np.where(stereo, mp.chi2_stereo, mp.chi2_mono)
    full = StereoEdges(e_pose, e_pt, meas, stereo, sigma, huber)
    T, X, _ = bundle_adjust_points(T0, len(order) - 1, X0, full, calib, a.iterations, relative_tol=1e-7)
    keep = edge_chi2(T, X, full, calib, mp.min_depth) <= thr
    print(f"{len(order)} keyframes, {len(X0)} landmarks, {len(e_pose)} edges ({stereo.mean():.0%} stereo), "
          f"{keep.mean():.1%} inliers at the shipped offset")
    gt = src.ground_truth.poses
    gt_pos = np.stack([gt[k][:3, 3] for k in order])
    def kf_ate(Ts):
        est = np.stack([se3_inv(t)[:3, 3] for t in Ts])
        R, t, _ = umeyama_alignment(est.T, gt_pos.T)
        return 1000 * np.sqrt(np.mean(np.sum((R @ est.T + t.reshape(3, 1) - gt_pos.T) ** 2, axis=0)))
    print(f"keyframe SE(3) ATE: online (local BA only) {kf_ate(T0):.2f} mm, after the whole map's BA {kf_ate(T):.2f} mm")
    print("delta_px  robust_cost  cost_stereo_ur  sim3_scale  se3_ate_mm")
    for d in a.deltas:
        m = meas[keep].copy()
        m[:, 2] = np.where(stereo[keep], m[:, 2] - d, 0.0)
        e = StereoEdges(e_pose[keep], e_pt[keep], m, stereo[keep], sigma[keep], huber[keep])
        Td, Xd, it = bundle_adjust_points(T, len(order) - 1, X, e, calib, a.iterations, relative_tol=1e-9)
        r, Pc, _, front = _project(Td, Xd, e, calib)
        cost = _robust_cost(r, front, e)[0]
        ur = float(np.sum((r[:, 2] / e.sigma) ** 2))
        est = np.stack([se3_inv(t)[:3, 3] for t in Td])
        _, _, s = umeyama_alignment(est.T, gt_pos.T, with_scale=True)
        R, t, _ = umeyama_alignment(est.T, gt_pos.T)
        ate = np.sqrt(np.mean(np.sum((R @ est.T + t.reshape(3, 1) - gt_pos.T) ** 2, axis=0)))
        print(f"{d:+.3f}  {cost:12.2f}  {ur:12.2f}  {s:.5f}  {1000 * ate:7.2f}  (it {it})")


if __name__ == "__main__":
    main()
