"""cProfile (thread-CPU clock) of the tracking thread, the stereo worker and local mapping on KITTI, in process.

    PYTHONPATH=$PWD python docs/results/s15_trackcpu/profile_threads.py --dataset kitti --reps 1 --top 40
"""
import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from canopy.backend import LocalMapper  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend import tracker_worker  # noqa: E402
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag  # noqa: E402
from canopy.sources import open_source  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--dataset", default="kitti")
ap.add_argument("--reps", type=int, default=1)
ap.add_argument("--top", type=int, default=40)
ap.add_argument("--sort", default="tottime")
a = ap.parse_args()
src = open_source(a.dataset, None)
frames = [src.frame(i) for i in range(len(src))]
prof_track, prof_work, prof_map = (cProfile.Profile(time.thread_time) for _ in range(3))
orig_run = tracker_worker.StereoJob._run


def run(self, *args, **kw):
    prof_work.enable()
    try:
        return orig_run(self, *args, **kw)
    finally:
        prof_work.disable()


tracker_worker.StereoJob._run = run
for _ in range(a.reps):
    cfg = load_run_config(a.dataset)
    tp, mp, rt = cfg.tracking, cfg.mapping, cfg.runtime
    if tp.opencv_threads > 0:
        cv2.setNumThreads(tp.opencv_threads)
    tracker, mapper = Tracker(calib := src.calibration, tp), LocalMapper(calib, mp)
    schedule = MapUpdateSchedule(effective_map_update_lag(rt.map_update_lag_frames, tp))
    for frame in frames:
        prof_track.enable()
        for update in schedule.take_due(frame.index):
            tracker.apply_map_update(update)
        res = tracker.track(frame)
        prof_track.disable()
        if res.is_keyframe and res.keyframe is not None:
            prof_map.enable()
            update = mapper.insert_keyframe(res.keyframe)
            prof_map.disable()
            schedule.keyframe_sent(res.keyframe.index, frame.index)
            schedule.hold(update)
n = len(frames) * a.reps
for name, p in (("TRACKING THREAD", prof_track), ("STEREO WORKER (StereoJob._run)", prof_work), ("LOCAL MAPPING", prof_map)):
    print(f"===== {name}: ms per frame = cumulative / {n}")
    st = pstats.Stats(p)
    st.sort_stats(a.sort).print_stats(a.top)
