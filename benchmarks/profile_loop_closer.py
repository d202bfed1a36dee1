"""The loop closer's CPU per keyframe, alone and repeatable (issue 10: "the loop closer never
delays tracking" — on 2 cores every millisecond it spends is taken from tracking and mapping).

Two steps:

``--record FILE``: runs the in-process lockstep reference of tracking -> local mapping -> loop
closing (``canopy.loop.sequential``) on a sequence and pickles every keyframe the loop closer is
given (its ``PlaceKeyframe`` and the window poses), with the run's ATE and detections.

``--replay FILE``: feeds the recorded keyframes to a fresh ``LoopCloser`` (the full BA after a loop
is run but not timed) and prints the closer's thread CPU per keyframe (p50 / p95 / mean / sum),
per verification outcome (matches, RANSAC, refinement, ok) and the detection counts; writes JSON.
``--set loop.field=value`` changes the closer's parameters for the replay (e.g.
``loop.verify_ransac=epnp``). The same recording replayed twice gives the same detections, so two
versions of the closer can be compared on identical input, one after the other.

    python benchmarks/profile_loop_closer.py --record /tmp/day.pkl --dataset synthetic --preset day-loop
    python benchmarks/profile_loop_closer.py --replay /tmp/day.pkl [--set loop.verify_ransac=epnp] [--out F.json]
"""
from __future__ import annotations

import argparse
import copy
import pickle
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config, parse_setting, with_settings  # noqa: E402
from canopy.loop import closer as closer_module  # noqa: E402
from canopy.loop.detector import LoopDetector  # noqa: E402
from canopy.loop.vocabulary import load_vocabulary  # noqa: E402
from canopy.report import write_json  # noqa: E402


def open_sequence(dataset: str, preset: str | None, max_frames: int | None):
    from canopy.app import prepare_synthetic
    from canopy.sources import open_source

    if dataset == "synthetic":
        path = prepare_synthetic(preset or "day-loop", None, 0, False)
        return open_source("euroc", path, max_frames=max_frames)
    return open_source(dataset, max_frames=max_frames)


def record(args) -> None:
    from canopy.loop.sequential import run_sequential_with_loops
    from canopy.metrics import evaluate_trajectory

    cfg = load_run_config(args.dataset)
    src = open_sequence(args.dataset, args.preset, args.max_frames)
    inputs = []
    add = closer_module.LoopCloser.add_keyframe

    def recording_add(self, kf, window_poses=None, epoch=None):
        inputs.append((copy.deepcopy(kf), {int(k): np.array(v) for k, v in (window_poses or {}).items()}))
        return add(self, kf, window_poses, epoch)

    closer_module.LoopCloser.add_keyframe = recording_add
    try:
        res = run_sequential_with_loops(src, load_vocabulary(cfg.loop.vocabulary), cfg.tracking, cfg.mapping, cfg.loop,
                                        max_frames=args.max_frames)
    finally:
        closer_module.LoopCloser.add_keyframe = add
    ate = evaluate_trajectory(res.trajectory, src.ground_truth)["ate"]["rmse"] if src.ground_truth is not None else None
    with open(args.record, "wb") as f:
        pickle.dump({"dataset": args.dataset, "preset": args.preset, "calibration": src.calibration,
                     "inputs": inputs, "detection": res.detection, "closures": len(res.closures), "ate": ate}, f)
    print(f"recorded {len(inputs)} keyframes -> {args.record}; loops {len(res.closures)}, ATE {ate}, {res.detection}")


def replay(args) -> dict:
    with open(args.replay, "rb") as f:
        rec = pickle.load(f)
    cfg = with_settings(load_run_config(rec["dataset"]), [parse_setting(s) for s in args.set])
    closer = closer_module.LoopCloser(rec["calibration"], cfg.loop, load_vocabulary(cfg.loop.vocabulary))
    verify_ms: dict[str, list[float]] = defaultdict(list)
    verify = LoopDetector.verify

    def timed_verify(self, query, cand):
        t0 = time.thread_time()
        v = verify(self, query, cand)
        verify_ms[v.kind].append((time.thread_time() - t0) * 1e3)
        return v

    LoopDetector.verify = timed_verify
    step_ms, closed = [], []
    try:
        for kf, window_poses in rec["inputs"]:
            kf = copy.deepcopy(kf)
            t0 = time.thread_time()
            closure = closer.add_keyframe(kf, window_poses)
            step_ms.append((time.thread_time() - t0) * 1e3)
            if closure is not None:
                closed.append({"query": int(kf.index), "candidate": int(closure.constraint.candidate),
                               "inliers": int(closure.constraint.n_inliers)})
                if closer.ba_pending:
                    closer.global_bundle_adjust()
    finally:
        LoopDetector.verify = verify
    s = np.asarray(step_ms)
    d = closer.detector.stats
    out = {"benchmark": "profile_loop_closer", "recording": str(args.replay), "settings": list(args.set),
           "keyframes": len(s), "step_cpu_ms": {"p50": float(np.percentile(s, 50)), "p95": float(np.percentile(s, 95)),
                                                "mean": float(s.mean()), "sum": float(s.sum())},
           "verification_cpu_ms": {k: {"n": len(v), "mean": float(np.mean(v)), "sum": float(np.sum(v))}
                                   for k, v in sorted(verify_ms.items())},
           "detection": {"queries": d.queries, "candidates": d.candidates, "consistent": d.consistent,
                         "verified": d.verified, "rejected": dict(d.rejected)},
           "closed": closed, "recorded_closures": rec["closures"]}
    print(f"{len(s)} keyframes, loop closer thread CPU per keyframe: p50 {out['step_cpu_ms']['p50']:.1f} ms, "
          f"p95 {out['step_cpu_ms']['p95']:.1f} ms, mean {out['step_cpu_ms']['mean']:.1f} ms, sum {s.sum() / 1e3:.1f} s")
    print(f"{'verification':>14s} {'n':>6s} {'mean ms':>8s} {'sum ms':>8s}")
    for k, v in out["verification_cpu_ms"].items():
        print(f"{k:>14s} {v['n']:6d} {v['mean']:8.1f} {v['sum']:8.0f}")
    print(f"detection {out['detection']}; closed {closed} (recording: {rec['closures']} loop(s))")
    if args.out:
        write_json(args.out, out)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--record", metavar="FILE", help="run the in-process reference and record the closer's input")
    mode.add_argument("--replay", metavar="FILE", help="replay a recording through a fresh loop closer")
    ap.add_argument("--dataset", default="synthetic", choices=["synthetic", "kitti", "euroc"])
    ap.add_argument("--preset", default="day-loop", help="generated preset (--dataset synthetic)")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="loop.FIELD=VALUE")
    ap.add_argument("--out", default=None, help="JSON output of --replay")
    args = ap.parse_args(argv)
    record(args) if args.record else replay(args)


if __name__ == "__main__":
    main()
