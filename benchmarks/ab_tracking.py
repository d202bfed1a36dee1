#!/usr/bin/env python
"""This checkout's tracking (and local mapping) against another checkout's, frame by frame
(issue 8: speed).

Two child processes, one per checkout (``--base`` and this one), each run the in-process lockstep
loop of ``benchmarks/profile_tracking.py`` (map updates applied at their frame, ``Tracker.track``,
``LocalMapper.insert_keyframe`` of its keyframes) on the same frames, with the tracking process's
settings (``TrackingParams.opencv_threads`` where the checkout has it). They take turns frame by
frame: the parent tells one child to process frame k, waits for its figures, then the other, and
which child goes first alternates. So both meet the same machine load, and neither runs while the
other does (on a shared 2-core machine, two whole runs started together still differ by ±10 %).

Per frame and side: the tracking thread's CPU (``time.thread_time`` around ``track``), the process
CPU of ``track`` (``time.process_time``: with the worker thread and OpenCV's / OpenBLAS's threads),
the stage CPU the tracker reports (``orb``, ``orb_right``, ``stereo_worker``, ``track_local_map``,
...), the tracking thread's wall minus CPU minus run-queue wait ("blocked": waiting for the worker,
for a pool thread), the wall time of ``track`` (loaded machines inflate it: compare the blocked time),
the worker thread's CPU (the sum of its stages: ``orb_right``, ``stereo_pyramids``, ``stereo_worker``),
and the process CPU of local mapping. Prints p50 (and mean) of each side, their ratio, and whether
the poses are bit-identical.

    git archive <base-commit> | tar -x -C /tmp/base
    PYTHONPATH=$PWD python benchmarks/ab_tracking.py --base /tmp/base --dataset kitti --reps 2
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# stereo_pyramids: the worker's SAD pyramids built before it waits for the left keypoints (s12)
STAGES = ("orb", "orb_right", "stereo_pyramids", "stereo_worker", "match_motion", "pnp", "track_local_map", "keyframe",
          "stereo")
WORKER_STAGES = ("orb_right", "stereo_pyramids", "stereo_worker")


def child(dataset: str, settings: list[str]) -> None:
    """One side: read "go" lines from stdin, process the next frame, answer one JSON line."""
    import cv2

    sys.path.insert(0, os.getcwd())
    from canopy.backend import LocalMapper
    from canopy.config import load_run_config
    from canopy.frontend import Tracker
    from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag
    from canopy.sources import open_source

    cfg = load_run_config(dataset)
    tp, rt = cfg.tracking, cfg.runtime
    if settings:  # --set tracking.FIELD=VALUE (this side only)
        import dataclasses

        import yaml
        sets = {}
        for item in settings:
            key, value = item.split("=", 1)
            section, field = key.split(".", 1)
            if section != "tracking" or not hasattr(tp, field):
                raise SystemExit(f"ab_tracking: --set {item}: only tracking.FIELD=VALUE of TrackingParams")
            sets[field] = yaml.safe_load(value)
        tp = dataclasses.replace(tp, **sets).validate()
    n_cv = int(getattr(tp, "opencv_threads", 0))
    if n_cv > 0:  # as the tracking actor sets its process
        cv2.setNumThreads(n_cv)
    src = open_source(dataset, None)
    frames = [src.frame(i) for i in range(len(src))]
    print(json.dumps({"frames": len(frames)}), flush=True)
    for line in sys.stdin:
        if line.strip() != "go":
            break
        tracker, mapper = Tracker(src.calibration, tp), LocalMapper(src.calibration, cfg.mapping)
        schedule = MapUpdateSchedule(effective_map_update_lag(rt.map_update_lag_frames, tp))
        poses = []
        for frame in frames:
            if frame.index > 0 and sys.stdin.readline().strip() != "go":
                return
            for update in schedule.take_due(frame.index):
                tracker.apply_map_update(update)
            with open("/proc/thread-self/schedstat") as f:
                run0, wait0 = (int(x) for x in f.read().split()[:2])
            w0, t0, p0 = time.perf_counter(), time.thread_time(), time.process_time()
            res = tracker.track(frame)
            wall, thread, proc = time.perf_counter() - w0, time.thread_time() - t0, time.process_time() - p0
            with open("/proc/thread-self/schedstat") as f:
                run1, wait1 = (int(x) for x in f.read().split()[:2])
            mapping = 0.0
            if res.is_keyframe and res.keyframe is not None:
                p1 = time.process_time()
                update = mapper.insert_keyframe(res.keyframe)
                mapping = time.process_time() - p1
                schedule.keyframe_sent(res.keyframe.index, frame.index)
                schedule.hold(update)
            poses.append(res.T_world_cam.tolist())
            out = {"thread": thread * 1e3, "process": proc * 1e3, "mapping": mapping * 1e3, "wall": wall * 1e3,
                   "blocked": (wall - (run1 - run0) * 1e-9 - (wait1 - wait0) * 1e-9) * 1e3,
                   "stages": {s: res.timings.get(s + "_cpu") for s in STAGES},
                   "stereo_wait": res.timings.get("stereo")}
            if frame.index == len(frames) - 1:
                out["poses"] = poses
            print(json.dumps(out), flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, help="the other checkout's root")
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--out", type=Path, default=None, help="JSON of every frame's figures")
    ap.add_argument("--set", dest="settings", action="append", default=[], metavar="tracking.FIELD=VALUE",
                    help="override a tracking setting on this checkout's side only (repeatable), e.g. "
                         "--set tracking.stereo_matcher=flow against --base of the same commit")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.dataset, a.settings)
        return 0
    if a.base is None or not (a.base / "canopy").is_dir():
        raise SystemExit("ab_tracking: --base must be a checkout (a folder with canopy/)")
    sides = {"base": a.base.resolve(), "this": ROOT}
    procs = {}
    for name, root in sides.items():
        env = dict(os.environ, PYTHONPATH=str(root))
        extra = [f"--set={item}" for item in a.settings] if name == "this" else []
        procs[name] = subprocess.Popen([sys.executable, str(ROOT / "benchmarks" / "ab_tracking.py"), "--child",
                                        "--dataset", a.dataset, *extra], cwd=root, env=env, text=True,
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    n = {name: json.loads(p.stdout.readline())["frames"] for name, p in procs.items()}
    if len(set(n.values())) != 1:
        raise SystemExit(f"ab_tracking: the checkouts read different frame counts {n}")
    frames = n["this"]
    rec: dict[str, list[dict]] = {"base": [], "this": []}
    identical = []
    for rep in range(a.reps):
        last = {}
        for k in range(frames):
            order = ("base", "this") if (k + rep) % 2 == 0 else ("this", "base")
            for name in order:
                procs[name].stdin.write("go\n")
                procs[name].stdin.flush()
                r = json.loads(procs[name].stdout.readline())
                if "poses" in r:
                    last[name] = np.array(r.pop("poses"))
                rec[name].append(r)
        identical.append(bool(np.array_equal(last["base"], last["this"])))
    for p in procs.values():
        p.stdin.close()
        p.wait()

    def stat(name: str, get) -> tuple[float, float]:
        v = np.array([x for x in (get(r) for r in rec[name]) if x is not None], float)
        return (float(np.median(v)), float(np.mean(v))) if len(v) else (float("nan"), float("nan"))

    rows = [("tracking thread CPU", lambda r: r["thread"]), ("track() process CPU", lambda r: r["process"]),
            ("tracking thread blocked", lambda r: r["blocked"]), ("stereo wait (wall)", lambda r: r["stereo_wait"]),
            ("track() wall", lambda r: r.get("wall")),
            # the worker thread's CPU: its stages (a base without a stage counts it as 0)
            ("worker thread CPU (stages)", lambda r: sum(r["stages"].get(s) or 0.0 for s in WORKER_STAGES) or None)]
    rows += [(f"stage {s}", lambda r, s=s: r["stages"].get(s)) for s in STAGES if s != "stereo"]
    rows += [("mapping CPU per frame", lambda r: r["mapping"])]
    print(f"{a.dataset}: {frames} frames x {a.reps} reps, frame by frame alternating; ms p50 (mean)")
    print(f"{'':26s} {'base':>16s} {'this':>16s} {'ratio p50':>9s} {'ratio mean':>10s}")
    table = {}
    for label, get in rows:
        (bp, bm), (tp, tm) = stat("base", get), stat("this", get)
        table[label] = {"base_p50": bp, "base_mean": bm, "this_p50": tp, "this_mean": tm}
        rp = tp / bp if bp else float("nan")
        rm = tm / bm if bm else float("nan")
        print(f"{label:26s} {bp:7.2f} ({bm:6.2f}) {tp:7.2f} ({tm:6.2f}) {rp:9.3f} {rm:10.3f}")
    print(f"poses bit-identical in {sum(identical)} of {len(identical)} reps")
    if a.out:
        a.out.write_text(json.dumps({"dataset": a.dataset, "reps": a.reps, "base": str(a.base), "table": table,
                                     "identical": identical, "frames": rec, "date": time.strftime("%Y-%m-%d %H:%M")}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
