#!/usr/bin/env python
"""Why is a dark run less accurate than the clean one? Frame-by-frame evidence (issue 9).

Runs the tracker and local mapper in process (``canopy.pipeline``'s loop, no loop
closing) on a degraded copy of a sequence (``tools/degrade_sequence.py`` output) with the
enhancement and the FAST-threshold rule of the actors (``enhance_pair`` + ``actor_fast``
below mirror ``actors/enhancement.py`` and ``actors/tracking.py``), and prints per frame and
in total:

* features (left), stereo matches, and their disparity error against SGBM on the *clean*
  pair (median |error|, signed bias of the matches within 1 px, fraction off by > 1 px):
  bad stereo depth from noisy sub-pixel refinement shows as a wide or biased error;
* map matches and inliers of the pose;
* the frame-to-frame motion against ground truth (length ratio: a depth bias shows as a
  ratio ≠ 1) and ATE (SE(3) and Sim(3) aligned; its scale).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python benchmarks/bench_enhance_diagnose.py \\
        --path /tmp/kitti_g0.06 [--clean data/kitti06_snippet] [--enh name=value ...] [--set tracking.name=value ...]
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.backend import LocalMapper  # noqa: E402
from canopy.backend.final_ba import finish_map  # noqa: E402
from canopy.config import load_run_config, parse_value  # noqa: E402
from canopy.degrade import disparity_sgbm  # noqa: E402
from canopy.enhance import make_enhancer, pair_arguments, tracking_fast_arguments  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.metrics import ape, ate_sim3  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402


def enhance_pair(enhancer, left, right):
    """As actors/enhancement.py: decide on the left image, the same treatment (and σ) for the right."""
    le, info = enhancer(left)
    re, _ = enhancer(right, **pair_arguments(info))
    return le, re, info


def actor_fast(enh, info, left, n_features, rule="actor"):
    """As actors/tracking.py (``tracking_fast_arguments``, only for ``afe`` / ``auto``).
    ``rule`` "N": a fixed threshold N on enhanced frames instead (for experiments)."""
    if rule != "actor" and info["method"] != "none":
        return dict(fast_threshold=int(rule))
    if enh.method not in ("afe", "auto"):
        return {}
    return tracking_fast_arguments(left, info["method"], enh, n_features)


def stereo_errors(tracker, frame, kwargs, ref_disp):
    """Disparity errors of the tracker's own stereo matches against the clean SGBM disparity."""
    p = tracker.params
    ex_l, ex_r = tracker.extractor, tracker.extractor_right
    thr = kwargs.get("fast_threshold")
    fl = ex_l.extract(frame.left, thr, kwargs.get("fast_fallback"), kwargs.get("fast_min_keypoints", 0))
    fr = ex_r.extract(frame.right, thr, kwargs.get("fast_fallback"), kwargs.get("fast_min_keypoints", 0))
    st = match_stereo(fl, fr, frame.left, frame.right, tracker.calib, p)
    ok = st.valid
    uv = fl.uv[ok]
    d_est = uv[:, 0] - st.u_right[ok]
    h, w = ref_disp.shape
    d_ref = ref_disp[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
    scored = d_ref > 0
    err = d_est[scored] - d_ref[scored]
    near = np.abs(err) <= 1.0
    return {"kp": len(fl), "stereo": int(ok.sum()), "octave0": float(np.mean(fl.octave == 0)) if len(fl) else 0.0,
            "d_med_abs": float(np.median(np.abs(err))) if len(err) else np.nan,
            "d_bias": float(np.mean(err[near])) if near.any() else np.nan,
            "d_rel_bias": float(np.mean(err[near] / d_ref[scored][near])) if near.any() else np.nan,
            "d_bad": float(np.mean(~near)) if len(err) else np.nan}


class TrajectoryRecorder:
    """The in-process loop's bookkeeping, as the actors do it: a keyframe goes to the local mapper (its map update
    scheduled by ``schedule``), and each frame's pose is kept relative to its reference keyframe, so that the
    trajectory is rebuilt on the mapper's final keyframe poses (the actors' trajectory writer)."""

    def __init__(self):
        self.poses, self.rel, self.refs, self.statuses = [], [], [], []

    def add(self, res, frame_index: int, schedule, mapper) -> None:
        if res.is_keyframe and res.keyframe is not None:
            schedule.keyframe_sent(res.keyframe.index, frame_index)
            schedule.hold(mapper.insert_keyframe(res.keyframe))
        self.poses.append(res.T_world_cam.copy())
        self.rel.append(None if res.T_ref_cam is None else res.T_ref_cam.copy())
        self.refs.append(res.reference_kf_index)
        self.statuses.append(res.status)

    def trajectory(self, mapper) -> tuple[np.ndarray, np.ndarray]:
        """(N×4×4 poses on the final keyframes, N booleans: tracked)."""
        kf = mapper.keyframe_poses()
        est = np.array([kf[r] @ T if T is not None and r in kf else P
                        for T, r, P in zip(self.rel, self.refs, self.poses)])
        return est, np.array([s in ("ok", "init") for s in self.statuses])


def run(path, clean_path, dataset, enh_sets, track_sets, max_frames=None, per_frame=False, stereo=True,
        fast_rule="actor", kind=None, map_sets=None):
    """``dataset``: the config (configs/<dataset>.yaml); ``kind``: the source layout (default ``dataset``);
    ``map_sets``: mapping settings over the config's (e.g. ``{"window_size": 5}``)."""
    cfg = load_run_config(dataset)
    enh = replace(cfg.enhancement, **enh_sets)
    tp = replace(cfg.tracking, **track_sets)
    src = open_source(kind or dataset, path, max_frames=max_frames)
    clean = open_source(kind or dataset, clean_path, max_frames=max_frames)
    enhancer = make_enhancer(enh)
    tracker = Tracker(src.calibration, tp)
    mapper = LocalMapper(src.calibration, replace(cfg.mapping, **(map_sets or {})))
    # map updates applied when the actors' lockstep applies them (runtime.map_update_lag_frames)
    schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
    rows, recorder = [], TrajectoryRecorder()
    for i in range(len(src)):
        fr = src.frame(i)
        for update in schedule.take_due(fr.index):
            tracker.apply_map_update(update)
        le, re, info = enhance_pair(enhancer, fr.left, fr.right)
        frame = StereoFrame(fr.index, fr.timestamp, le, re)
        kw = actor_fast(enh, info, le, tp.n_features, fast_rule)
        row = {"i": i, "method": info["method"], "sigma": info["noise_sigma"], "thr": kw.get("fast_threshold")}
        if stereo:
            c = clean.frame(i)
            ref = disparity_sgbm(c.left, c.right).astype(np.float64)
            ref[ref <= 0] = -1.0
            row.update(stereo_errors(tracker, frame, kw, ref))
        # the enhancement's noise sigma of the pair, as actors/tracking.py hands it over (the fill-in gate)
        res = tracker.track(frame, **kw, sensor_sigma=info["noise_sigma"])
        row.update(status=res.status, inl=int(res.n_inliers), matches=int(res.n_matches),
                   noise=res.noise_sigma, reason=res.lost_reason)
        recorder.add(res, fr.index, schedule, mapper)
        rows.append(row)
    finish_map(mapper)   # mapping.final_ba, as the actors' local mapping at the end of the stream
    est, tracked = recorder.trajectory(mapper)
    gt = clean.ground_truth.poses[: len(est)]
    out = {"tracked": float(tracked.mean())}
    if tracked.sum() >= 3:
        try:
            a, s = ape(est[tracked], gt[tracked], "se3"), ate_sim3(est[tracked], gt[tracked])
            out.update(ate=a["rmse"], ate_sim3=s["rmse"], scale=s["scale"])
        except ValueError as exc:  # e.g. every tracked pose at one place
            out["ate_error"] = str(exc)
    for i in range(1, len(est)):
        de, dg = se3_inv(est[i - 1]) @ est[i], se3_inv(gt[i - 1]) @ gt[i]
        tg = np.linalg.norm(dg[:3, 3])
        rows[i]["ratio"] = float(np.linalg.norm(de[:3, 3]) / tg) if tg > 0.05 else np.nan
        rows[i]["dt_err"] = float(np.linalg.norm(de[:3, 3] - dg[:3, 3]))
    keys = ["kp", "stereo", "d_med_abs", "d_bias", "d_rel_bias", "d_bad", "inl", "matches", "ratio", "dt_err", "sigma",
            "thr", "noise", "octave0"]
    for k in keys:
        vals = [r[k] for r in rows if r.get(k) is not None and np.isfinite(r.get(k))]
        out[f"med_{k}"] = float(np.median(vals)) if vals else None
    if per_frame:
        for r in rows:
            print(" ".join(f"{k}={r[k]:.3f}" if isinstance(r.get(k), float) else f"{k}={r.get(k)}"
                           for k in ["i", "status", "reason"] + keys if k in r))
    return out, rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--path", required=True, help="degraded sequence folder")
    ap.add_argument("--clean", default=None, help="the clean sequence (default: the bundled snippet)")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--enh", action="append", default=[], help="EnhanceParams override name=value")
    ap.add_argument("--set", action="append", default=[], help="TrackingParams override name=value")
    ap.add_argument("--fast", default="actor", help="FAST threshold on enhanced frames: actor (as the "
                    "tracking actor) or a fixed number")
    ap.add_argument("--per-frame", action="store_true")
    ap.add_argument("--no-stereo", action="store_true", help="skip the disparity-error scoring (faster)")
    args = ap.parse_args()
    enh = {k: parse_value(v) for k, v in (s.split("=", 1) for s in args.enh)}
    trk = {k: parse_value(v) for k, v in (s.split("=", 1) for s in args.set)}
    clean = args.clean or BUNDLED_DATA[args.dataset]
    out, _ = run(args.path, clean, args.dataset, enh, trk, args.max_frames, args.per_frame, not args.no_stereo,
                 args.fast)
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in out.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
