#!/usr/bin/env python
"""CPU of the step check (canopy.frontend.step_check) per call, on clean KITTI 06 frame 3 after frames 0-2
tracked: stage 2 alone, the check when it does not fire, and when it fires (a first solution 0.4 m
short along the optical axis: the re-solve from the prediction runs and replaces it). Median
``time.thread_time`` of 30 calls each (CPU, so it holds under load).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python benchmarks/time_step_check.py
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.frontend.matching import as_words  # noqa: E402
from canopy.frontend.pose import PoseEstimate  # noqa: E402
from canopy.frontend.step_check import local_map_pose, recheck_step  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402


def main() -> int:
    src = open_source("kitti", BUNDLED_DATA["kitti"], max_frames=4)
    p = replace(load_run_config("kitti").tracking, parallel_extraction=False, parallel_stereo=False,
                step_max_deviation_m=0.2)
    tracker = Tracker(src.calibration, p)
    for i in range(3):
        tracker.track(src.frame(i))
    ex = tracker.extract(src.frame(3))
    feats, stereo = ex.left, tracker._stereo(ex.stereo, {})
    words, view = as_words(feats.descriptors), tracker._map_view()
    T_pred = se3_inv(tracker._T_last @ tracker._velocity)
    stage1 = tracker._initial_matches(T_pred, view, feats, words)
    T_r, inl = tracker._ransac(3, stage1[0], feats.uv[stage1[1]])
    first = local_map_pose(tracker, T_r, view, feats, words, lambda: stereo, stage1, inl)
    T_short = se3_inv(T_pred)
    T_short[:3, 3] -= 0.4 * T_short[:3, 2]
    est = first[0]
    short = (PoseEstimate(se3_inv(T_short), np.zeros(0, bool), est.information, np.zeros(0)), first[1], first[2])
    calls = {"stage 2 (local_map_pose)": lambda: local_map_pose(tracker, T_r, view, feats, words, lambda: stereo,
                                                                stage1, inl),
             "step check, not fired": lambda: recheck_step(tracker, first, T_pred, view, feats, words, lambda: stereo,
                                                           stage1, inl),
             "step check, fired": lambda: recheck_step(tracker, short, T_pred, view, feats, words, lambda: stereo,
                                                       stage1, inl)}
    for name, fn in calls.items():
        ts = []
        for _ in range(30):
            c = time.thread_time()
            fn()
            ts.append(time.thread_time() - c)
        print(f"{name}: median {np.median(ts) * 1e3:.2f} ms CPU (30 calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
