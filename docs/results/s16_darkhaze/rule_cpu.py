#!/usr/bin/env python
"""s16-darkhaze: thread CPU of the uncertain-stereo rule (TrackerMeasurementsMixin._uncertain_stereo)
per frame on a KITTI cell, in process, as diag_frames.py runs it. Usage: rule_cpu.py CELL_DIR [--set ...]"""
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from benchmarks.bench_enhance_diagnose import actor_fast, enhance_pair  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.tracker_measurements import TrackerMeasurementsMixin  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

spent, flagged = [], []
orig = TrackerMeasurementsMixin._uncertain_stereo


def timed(self, stereo):
    t0 = time.thread_time()
    out = orig(self, stereo)
    spent.append(1000 * (time.thread_time() - t0))
    if out is not None:
        flagged.append((int(out.sum()), int(stereo.valid.sum())))
    return out


TrackerMeasurementsMixin._uncertain_stereo = timed
cfg = load_run_config("kitti")
tp = replace(cfg.tracking, uncertain_stereo_max_rel_sigma=0.1, uncertain_stereo_bearing_only=False,
             uncertain_stereo_landmarks=False)
enh = replace(cfg.enhancement, method="auto")
src = open_source("kitti", None if sys.argv[1] == "clean" else sys.argv[1])
enhancer, tracker = make_enhancer(enh), Tracker(src.calibration, tp)
mapper = LocalMapper(src.calibration, cfg.mapping)
schedule = MapUpdateSchedule(effective_map_update_lag(cfg.runtime.map_update_lag_frames, tp, cfg.runtime.sensor))
track_cpu = []
for i in range(len(src)):
    fr = src.frame(i)
    for u in schedule.take_due(fr.index):
        tracker.apply_map_update(u)
    le, re, info = enhance_pair(enhancer, fr.left, fr.right)
    t0 = time.thread_time()
    res = tracker.track(StereoFrame(fr.index, fr.timestamp, le, re), **actor_fast(enh, info, le, tp.n_features))
    track_cpu.append(1000 * (time.thread_time() - t0))
    if res.is_keyframe and res.keyframe is not None:
        schedule.keyframe_sent(res.keyframe.index, fr.index)
        schedule.hold(mapper.insert_keyframe(res.keyframe))
print(f"{Path(sys.argv[1]).name}: rule {np.median(spent):.2f} ms p50, {np.percentile(spent, 90):.2f} p90 thread CPU "
      f"over {len(spent)} frames; track() thread CPU p50 {np.median(track_cpu):.1f} ms; flagged per frame p50 "
      f"{np.median([f for f, _ in flagged]) if flagged else 0:.0f} of {np.median([n for _, n in flagged]) if flagged else 0:.0f} "
      f"stereo points ({len(flagged)} frames over the noise gate)")
