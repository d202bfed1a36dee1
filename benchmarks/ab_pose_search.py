#!/usr/bin/env python
"""This checkout's ``refine_pose`` and ``match_in_window`` against another checkout's, call by call
(issue 8: speed).

Runs the in-process lockstep loop (``benchmarks/profile_tracking.py``'s: map updates at their frame,
``Tracker.track``, ``LocalMapper.insert_keyframe``) once with this checkout, recording every call the
tracker's pose solving makes to ``refine_pose`` (the motion-only refinement) and ``match_in_window``
(the motion-model and local-map searches), then replays each recorded call with both checkouts'
functions, alternating which goes first, and reports the tracking thread's CPU per call
(``time.thread_time``: load-robust) and whether the outputs are identical (every array, bit for bit).

    git archive <base-commit> | tar -x -C /tmp/base
    PYTHONPATH=$PWD python benchmarks/ab_pose_search.py --base /tmp/base --dataset kitti --reps 4
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import canopy.frontend.map_tracking as map_tracking  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend import matching as new_matching  # noqa: E402
from canopy.frontend import pose as new_pose  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def record(dataset: str) -> dict:
    """Every refine_pose / match_in_window call of the tracker on the dataset: (args, kwargs)."""
    src = open_source(dataset, None)
    cfg = load_run_config(dataset)
    tp, mp, rt = cfg.tracking, cfg.mapping, cfg.runtime
    if tp.opencv_threads > 0:
        cv2.setNumThreads(tp.opencv_threads)
    calls = {"refine_pose": [], "match_in_window": []}
    orig = {name: getattr(map_tracking, name) for name in calls}

    def recorder(name):
        def call(*a, **k):
            calls[name].append((a, k))
            return orig[name](*a, **k)
        return call

    try:
        for name in calls:
            setattr(map_tracking, name, recorder(name))
        tracker, mapper = Tracker(src.calibration, tp), LocalMapper(src.calibration, mp)
        schedule = MapUpdateSchedule(effective_map_update_lag(rt.map_update_lag_frames, tp))
        for i in range(len(src)):
            frame = src.frame(i)
            for update in schedule.take_due(frame.index):
                tracker.apply_map_update(update)
            res = tracker.track(frame)
            if res.is_keyframe and res.keyframe is not None:
                schedule.keyframe_sent(res.keyframe.index, frame.index)
                schedule.hold(mapper.insert_keyframe(res.keyframe))
    finally:
        for name, fn in orig.items():
            setattr(map_tracking, name, fn)
    return calls


def _module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _identical(a, b) -> bool:
    if hasattr(a, "T_cam_world"):  # PoseEstimate
        a, b = (a.T_cam_world, a.inliers, a.information, a.chi2), (b.T_cam_world, b.inliers, b.information, b.chi2)
    return all(np.array_equal(x, y) and x.dtype == y.dtype and np.array_equal(np.signbit(x), np.signbit(y))
               for x, y in zip(a, b))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, required=True, help="the other checkout's root")
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--reps", type=int, default=4)
    a = ap.parse_args()
    calls = record(a.dataset)
    base = {"refine_pose": _module(a.base / "canopy/frontend/pose.py", "base_pose").refine_pose,
            "match_in_window": _module(a.base / "canopy/frontend/matching.py", "base_matching").match_in_window}
    new = {"refine_pose": new_pose.refine_pose, "match_in_window": new_matching.match_in_window}
    print(f"{a.dataset}: thread CPU ms per call, {a.reps} reps alternating")
    for name, recorded in calls.items():
        kinds = {}
        for args, kw in recorded:  # match_in_window: the motion-model search vs the scaled local-map search
            kinds.setdefault("scaled" if kw.get("r_scale") is not None else "", []).append((args, kw))
        for kind, group in kinds.items():
            t = {"base": 0, "this": 0}
            same = 0
            for rep in range(a.reps):
                for args, kw in group:
                    out = {}
                    for side in (("base", "this") if rep % 2 == 0 else ("this", "base")):
                        fn = base[name] if side == "base" else new[name]
                        t0 = time.thread_time_ns()
                        out[side] = fn(*args, **kw)
                        t[side] += time.thread_time_ns() - t0
                    same += _identical(out["base"], out["this"])
            n = a.reps * len(group)
            label = f"{name} {kind}".strip()
            print(f"{label:26s} calls {len(group):4d}  base {t['base'] / n / 1e6:7.3f}  this {t['this'] / n / 1e6:7.3f}  "
                  f"ratio {t['this'] / max(t['base'], 1):.3f}  identical {same}/{n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
