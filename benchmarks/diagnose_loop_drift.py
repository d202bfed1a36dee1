#!/usr/bin/env python
"""Which loop-closing stage gains or loses accuracy? In-process lockstep, against ground truth.

Runs ``canopy.loop.sequential.run_sequential_with_loops`` (tracking -> local mapping -> loop
closer after every keyframe, the full BA at once) with a dataset's shipped config and
``--set`` overrides, and reports for every closed loop, against the generator's ground truth:

- the loop constraint's own error (verified T_cand_query against the true relative pose),
  its descriptor matches and inliers, and how many of those inliers are contour (bearing-only)
  keypoints of the query / candidate (depth > 0, no right column);
- the keyframe trajectory's ATE (SE(3)-aligned, keyframes known so far) before the loop,
  after the pose graph, and after the full BA;
- the fusions and loop connections, and the full BA's outliers and pixel noise.

Then the final frame trajectory's ATE, with the rms per world axis.

    PYTHONPATH=$PWD CANOPY_CACHE_DIR=/work/cache python benchmarks/diagnose_loop_drift.py \
        --path /work/cache/synthetic/day-loop-seed0-full [--set tracking.contour_enabled=true ...]
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config, parse_setting, with_settings  # noqa: E402
from canopy.frontend.geometry import rotation_angle, se3_inv  # noqa: E402
from canopy.loop import closer as closer_mod  # noqa: E402
from canopy.loop.sequential import run_sequential_with_loops  # noqa: E402
from canopy.loop.vocabulary import load_vocabulary  # noqa: E402
from canopy.metrics import align_trajectory, ape  # noqa: E402
from canopy.enhance.pair import PairEnhancer  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def kf_ate(poses: dict[int, np.ndarray], gt: np.ndarray) -> float:
    ks = sorted(k for k in poses if k < len(gt))
    if len(ks) < 3:
        return float("nan")
    return float(ape(np.array([poses[k] for k in ks]), gt[ks], align="se3")["rmse"])


def constraint_error(c, gt: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) of the verified loop pose against the true one."""
    T_true = se3_inv(gt[c.candidate]) @ gt[c.query]
    E = se3_inv(T_true) @ c.T_cand_query
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(rotation_angle(E[:3, :3])))


class EnhancedSource:
    """The source with every pair through ``PairEnhancer`` (what the enhancement actor does), so that
    the in-process reference sees the images tracking sees through the actors (dusk-loop: ``auto``)."""

    def __init__(self, source, params):
        self.source = source
        self.enhancer = PairEnhancer(replace(params, pair_threads=1))
        self.methods: dict[str, int] = {}

    def __len__(self):
        return len(self.source)

    def __getattr__(self, name):
        return getattr(self.source, name)

    def frame(self, i):
        f = self.source.frame(i)
        left, right, info = self.enhancer(f.left, f.right)
        self.methods[info["method"]] = self.methods.get(info["method"], 0) + 1
        return replace(f, left=left, right=right)


class Recorder:
    """Wraps ``LoopCloser.close_loop`` / ``accept_ba`` of the closer the runner builds."""

    def __init__(self, gt: np.ndarray, record_path: str | None = None):
        self.gt = gt
        self.record_path = record_path
        self.rows: list[dict] = []
        self.closer = None

    def install(self):
        rec = self
        orig_close, orig_accept, orig_init = (closer_mod.LoopCloser.close_loop, closer_mod.LoopCloser.accept_ba,
                                              closer_mod.LoopCloser.__init__)

        def init(self, *a, **k):
            orig_init(self, *a, **k)
            rec.closer = self

        def close_loop(self, constraint, t_detect=0.0):
            if rec.record_path and not rec.rows:  # the closer as the first loop finds it (--record)
                with open(rec.record_path, "wb") as f:
                    pickle.dump({"closer": self, "constraint": constraint, "gt": rec.gt}, f)
            before = kf_ate(self.poses, rec.gt)
            q, c = self.detector.keyframes[constraint.query], self.detector.keyframes[constraint.candidate]
            contour_q = (np.asarray(q.depth) > 0) & (np.asarray(q.u_right) < 0)
            contour_c = (np.asarray(c.depth) > 0) & (np.asarray(c.u_right) < 0)
            closure = orig_close(self, constraint, t_detect)
            et, er = constraint_error(constraint, rec.gt)
            rec.rows.append(dict(query=constraint.query, candidate=constraint.candidate, n_matches=constraint.n_matches,
                                 n_inliers=constraint.n_inliers,
                                 contour_inl_q=int(contour_q[constraint.query_keypoints].sum()),
                                 contour_inl_c=int(contour_c[constraint.candidate_keypoints].sum()),
                                 err_t=et, err_r=er, fused=len(closure.fused),
                                 connections=int(closure.timings_ms.get("loop_connections", 0)),
                                 ate_before=before, ate_pgo=kf_ate(self.poses, rec.gt)))
            return closure

        def accept_ba(self, result):
            out = orig_accept(self, result)
            if rec.rows:
                rec.rows[-1].update(ate_ba=kf_ate(self.poses, rec.gt), ba_edges=int(result.n_edges),
                                    ba_outliers=int(result.n_outliers), ba_sigma=float(result.pixel_sigma))
            return out

        closer_mod.LoopCloser.__init__ = init
        closer_mod.LoopCloser.close_loop = close_loop
        closer_mod.LoopCloser.accept_ba = accept_ba
        # the runner imported the class itself: its name points at the same class object


def replay_first_loop(path: str, settings: list[str]) -> int:
    """--replay: the loop closer recorded at its first loop (--record), closed again with ``--set
    loop.*`` overrides of the correction (fusion, pose graph, full BA): keyframe ATE before, after
    the pose graph and after the full BA. Detection and the odometry up to that loop are the
    recorded ones, so this compares the correction alone, in a minute instead of a whole run."""
    with open(path, "rb") as f:
        rec = pickle.load(f)
    closer, constraint, gt = rec["closer"], rec["constraint"], rec["gt"]
    over = {}
    for s in settings:
        section, field, value = parse_setting(s)
        if section != "loop":
            raise SystemExit(f"--replay takes loop.* settings only (got {s!r}): the odometry is recorded")
        over[field] = value
    closer.params = replace(closer.params, **over)
    before = kf_ate(closer.poses, gt)
    t0 = time.perf_counter()
    closure = closer.close_loop(constraint)
    pgo = kf_ate(closer.poses, gt)
    ba = closer.global_bundle_adjust()
    print(f"replay {path} {settings or ''}: loop kf {constraint.query} -> {constraint.candidate}, fused "
          f"{len(closure.fused)}, connections {int(closure.timings_ms.get('loop_connections', 0))}; kf ATE before "
          f"{before:.4f} -> pose graph {pgo:.4f} -> full BA {kf_ate(closer.poses, gt):.4f} "
          f"(BA {ba.n_edges if ba else 0} edges, {ba.n_outliers if ba else 0} outliers, error "
          f"{ba.initial_error if ba else 0:.4g} -> {ba.final_error if ba else 0:.4g}), {time.perf_counter() - t0:.0f} s")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--record", default=None, help="pickle the loop closer as the first loop finds it here")
    ap.add_argument("--replay", default=None, help="close a --record'ed first loop again with --set loop.* (fast)")
    ap.add_argument("--path", help="generated sequence folder (EuRoC layout with ground truth)")
    ap.add_argument("--dataset", default="synthetic", help="config to start from (configs/<dataset>.yaml)")
    ap.add_argument("--set", action="append", default=[], help="section.field=value override (repeatable)")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--enhance", action="store_true",
                    help="run the config's enhancement on every pair first (as the actors do; off: raw frames)")
    ap.add_argument("--json", default=None, help="write the numbers here")
    args = ap.parse_args()
    if args.replay:
        return replay_first_loop(args.replay, args.set)
    if not args.path:
        ap.error("--path is required (except with --replay)")
    cfg = with_settings(load_run_config(args.dataset), [parse_setting(s) for s in args.set])
    src = open_source("euroc" if args.dataset == "synthetic" else args.dataset, args.path, max_frames=args.max_frames)
    if args.enhance:
        src = EnhancedSource(src, cfg.enhancement)
    n = len(src) if args.max_frames is None else min(len(src), args.max_frames)
    gt = src.ground_truth.poses[:n]
    rec = Recorder(gt, args.record)
    rec.install()
    t0 = time.perf_counter()
    res = run_sequential_with_loops(src, load_vocabulary(cfg.loop.vocabulary or None), cfg.tracking, cfg.mapping,
                                    cfg.loop, max_frames=args.max_frames)
    wall = time.perf_counter() - t0
    est = res.trajectory.poses
    a = ape(est, gt, align="se3")
    err = align_trajectory(est, gt, with_scale=False)[:, :3, 3] - gt[:, :3, 3]
    axes = np.sqrt((err**2).mean(axis=0))
    print(f"settings: {args.set or 'shipped config'}")
    for r in rec.rows:
        print(f"loop kf {r['query']} -> {r['candidate']}: matches {r['n_matches']} inliers {r['n_inliers']} "
              f"(contour q {r['contour_inl_q']} / c {r['contour_inl_c']}), constraint error {r['err_t']*100:.1f} cm "
              f"{r['err_r']:.2f} deg; fused {r['fused']} connections {r['connections']}; kf ATE before "
              f"{r['ate_before']:.4f} -> pose graph {r['ate_pgo']:.4f} -> full BA {r.get('ate_ba', float('nan')):.4f} "
              f"(BA {r.get('ba_edges', 0)} edges, {r.get('ba_outliers', 0)} outliers, sigma {r.get('ba_sigma', float('nan')):.2f} px)")
    print(f"detection: {res.detection}")
    if args.enhance:
        print(f"enhancement: {src.methods}")
    print(f"frame ATE {a['rmse']:.4f} m (max {a['max']:.3f}), x/y/z rms {axes[0]:.4f} / {axes[1]:.4f} / {axes[2]:.4f}, "
          f"keyframes {len(res.keyframe_trajectory.poses)}, loops {len(res.closures)}, wall {wall:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(dict(settings=args.set, ate=a["rmse"], ate_max=a["max"], axes=axes.tolist(),
                                                   loops=rec.rows, detection=res.detection, wall_s=wall), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
