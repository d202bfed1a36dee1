#!/usr/bin/env python
"""What lockstep throughput and tracking service time the actors' CPU allows on a dedicated 2-core
machine (s16-fps's model, s17-fps: + the tracking actor's service time per frame, i.e. what
bench_peers' ``track_ms_p50`` measures: from taking the frame to its pose, minus the wait for map
updates; + local mapping niceness variants).

The shared machine's load makes wall-clock throughput meaningless (run-queue waits of 90-120 ms
per frame at load 15-24), so this measures CPU instead and schedules it on a model of the quiet
machine:

1. record (in one process, thread CPU clocks): per frame the source's PNG decode, the tracking
   thread's extraction (noise + left ORB) and the rest of its frame, split at the wait for the
   worker's stereo (motion search + PnP before it, the local-map search, refinement and keyframe
   decision after), the worker's right ORB + SAD pyramids and its stereo matching, and per keyframe
   local mapping's ``insert_keyframe`` (local BA);
2. simulate the actors' lockstep protocol on two cores with Linux CFS's weighted sharing (nice 0:
   1024, nice 15: 36, nice 19: 15; each thread at most one core): the source reads up to
   ``prefetch`` frames ahead, enhancement (a fixed cost, measured through the actors) follows, the
   tracking thread and its worker as in ``canopy.frontend.tracker_worker``, local mapping's BA per
   keyframe, each update applied before frame k + 1 + lag. ``--order before``: the tracking thread
   waits for the due updates before extracting (main up to s15), ``ahead``: after (s16).

Messages, the supervisor, heartbeats and loop closing (~1-2 ms per frame) are left out, so
the model's frames/s is an upper bound; its use is the difference between the two orders.

    python docs/results/s17_fps/lockstep_service.py --replay docs/results/s16_fps/lockstep_model_kitti.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

WEIGHT = {0: 1024.0, 5: 335.0, 10: 110.0, 15: 36.0, 19: 15.0}  # CFS's sched_prio_to_weight


def record(dataset: str, max_frames: int | None) -> dict:
    """Thread CPU ms of each segment of each frame, in process, the default config."""
    from canopy.backend import LocalMapper
    from canopy.config import load_run_config
    from canopy.frontend import Tracker
    from canopy.pipeline import MapUpdateSchedule
    from canopy.sources import open_source

    cfg = load_run_config(dataset)
    src = open_source(dataset, None, max_frames=max_frames)
    tracker = Tracker(src.calibration, cfg.tracking)
    mapper = LocalMapper(src.calibration, cfg.mapping)
    schedule = MapUpdateSchedule(cfg.runtime.map_update_lag_frames)
    rows = []
    for i in range(len(src)):
        t0 = time.thread_time()
        frame = src.frame(i)
        decode = (time.thread_time() - t0) * 1e3
        for update in schedule.take_due(i):
            tracker.apply_map_update(update)
        res = tracker.track(frame)
        t = res.timings
        pre = t.get("noise_estimate_cpu", 0.0) + t["orb_cpu"]
        before_stereo = t.get("match_motion_cpu", 0.0) + t.get("pnp_cpu", 0.0)
        after = max(t["total_cpu"] - pre - before_stereo, 0.0)
        worker_a = t.get("orb_right_cpu", 0.0) + t.get("stereo_pyramids_cpu", 0.0)
        worker_b = t.get("stereo_worker_cpu", 0.0)
        ba = 0.0
        if res.is_keyframe:
            t0 = time.thread_time()
            update = mapper.insert_keyframe(res.keyframe)
            ba = (time.thread_time() - t0) * 1e3
            schedule.keyframe_sent(res.keyframe.index, i)
            schedule.hold(update)
        rows.append({"decode": decode, "pre": pre, "before_stereo": before_stereo, "after": after,
                     "worker_a": worker_a, "worker_b": worker_b, "keyframe": bool(res.is_keyframe), "ba": ba})
    return {"frames": rows, "lag": cfg.runtime.map_update_lag_frames, "prefetch": cfg.runtime.lockstep_prefetch_frames}


class Sim:
    """Weighted processor sharing of ``cores`` among runnable threads (each at most one core)."""

    def __init__(self, cores: int = 2):
        self.cores = cores
        self.now = 0.0
        self.threads: dict[str, dict] = {}

    def add(self, name: str, nice: int) -> None:
        self.threads[name] = {"w": WEIGHT[nice], "left": 0.0, "busy": False, "done": None}

    def start(self, name: str, work_ms: float, on_done) -> None:
        th = self.threads[name]
        assert not th["busy"], name
        th.update(left=max(work_ms, 1e-6), busy=True, done=on_done)

    def _rates(self) -> dict[str, float]:
        run = {n: t for n, t in self.threads.items() if t["busy"]}
        rates: dict[str, float] = {}
        cores = float(self.cores)
        while run:  # water-filling: a thread's share capped at one core, the rest redistributed
            total = sum(t["w"] for t in run.values())
            capped = {n for n, t in run.items() if cores * t["w"] / total >= 1.0}
            if not capped:
                for n, t in run.items():
                    rates[n] = cores * t["w"] / total
                break
            for n in capped:
                rates[n] = 1.0
                run.pop(n)
            cores -= len(capped)
            if cores <= 0:
                break
        return rates

    def step(self) -> bool:
        rates = self._rates()
        if not rates:
            return False
        name = min(rates, key=lambda n: self.threads[n]["left"] / rates[n])
        dt = self.threads[name]["left"] / rates[name]
        self.now += dt
        for n, r in rates.items():
            self.threads[n]["left"] -= r * dt
        finished = [n for n, r in rates.items() if self.threads[n]["left"] <= 1e-9]
        for n in finished:
            th = self.threads[n]
            th["busy"] = False
            cb, th["done"] = th["done"], None
            cb()
        return True


def simulate(rec: dict, order: str, enhance_ms: float, feeder_nice: int = 15, mapping_nice: int = 0,
             lag: int | None = None, prefetch: int | None = None, worker_nice: int = 0) -> dict:
    frames = rec["frames"]
    n = len(frames)
    lag = rec["lag"] if lag is None else lag
    prefetch = rec["prefetch"] if prefetch is None else prefetch
    sim = Sim(2)
    for name, nice in (("source", feeder_nice), ("enhancement", feeder_nice), ("tracking", 0), ("worker", worker_nice),
                       ("mapping", mapping_nice)):
        sim.add(name, nice)
    st = {"read": 0, "enhanced": 0, "enh_busy": False, "tracked": 0, "track_busy": False, "ba_queue": [],
          "ba_done": set(), "kf_of_frame": {}, "frame": None, "phase": None, "worker_b_done": False,
          "main_waits_stereo": False, "first_done": None, "last_done": None, "map_wait": 0.0, "wait_from": None,
          "worker_a_done": False, "pre_done": False}

    def due_missing(i: int) -> bool:  # an update due before frame i not yet computed
        return any(k + 1 + lag <= i and k not in st["ba_done"] for k in st["kf_of_frame"])

    def source_next():
        j = st["read"]
        if j < n and not sim.threads["source"]["busy"] and j - st["tracked"] <= prefetch:
            sim.start("source", frames[j]["decode"], source_done)

    def source_done():
        st["read"] += 1
        enh_next()
        source_next()

    def enh_next():
        j = st["enhanced"]
        if j < st["read"] and not sim.threads["enhancement"]["busy"]:
            sim.start("enhancement", enhance_ms, enh_done)

    def enh_done():
        st["enhanced"] += 1
        enh_next()
        track_next()

    def track_next():
        i = st["tracked"]
        if i >= n or st["track_busy"] or i >= st["enhanced"]:
            return
        st["track_busy"] = True
        st["frame"] = i
        st["start"] = sim.now
        st["wait_before"] = st["map_wait"]
        if order == "ahead":
            extract(i)
        else:
            wait_map(i, then=lambda: extract(i))

    def wait_map(i, then):
        if due_missing(i):
            st["wait_from"] = sim.now
            st["waiting"] = then
        else:
            then()

    def extract(i):
        f = frames[i]
        st.update(worker_a_done=False, worker_b_done=False, pre_done=False)
        sim.start("worker", f["worker_a"], lambda: worker_a_done(i))
        sim.start("tracking", f["pre"], lambda: pre_done(i))

    def worker_a_done(i):
        st["worker_a_done"] = True
        maybe_worker_b(i)

    def pre_done(i):
        st["pre_done"] = True
        maybe_worker_b(i)
        if order == "ahead":
            wait_map(i, then=lambda: sim.start("tracking", frames[i]["before_stereo"], lambda: before_done(i)))
        else:
            sim.start("tracking", frames[i]["before_stereo"], lambda: before_done(i))

    def maybe_worker_b(i):
        if st["worker_a_done"] and st["pre_done"] and not sim.threads["worker"]["busy"] and not st["worker_b_started"]:
            st["worker_b_started"] = True
            sim.start("worker", frames[i]["worker_b"], lambda: worker_b_done(i))

    def worker_b_done(i):
        st["worker_b_done"] = True
        if st["main_waits_stereo"]:
            st["main_waits_stereo"] = False
            sim.start("tracking", frames[i]["after"], lambda: frame_done(i))

    def before_done(i):
        if st["worker_b_done"]:
            sim.start("tracking", frames[i]["after"], lambda: frame_done(i))
        else:
            st["main_waits_stereo"] = True

    def frame_done(i):
        st["service"].append(sim.now - st["start"] - (st["map_wait"] - st["wait_before"]))
        st["tracked"] += 1
        st["track_busy"] = False
        st["worker_b_started"] = False
        st["first_done"] = sim.now if st["first_done"] is None else st["first_done"]
        st["last_done"] = sim.now
        if frames[i]["keyframe"]:
            st["kf_of_frame"][i] = True
            st["ba_queue"].append(i)
            ba_next()
        source_next()
        track_next()

    def ba_next():
        if st["ba_queue"] and not sim.threads["mapping"]["busy"]:
            k = st["ba_queue"].pop(0)
            sim.start("mapping", frames[k]["ba"], lambda: ba_done(k))

    def ba_done(k):
        st["ba_done"].add(k)
        ba_next()
        then = st.get("waiting")
        if then is not None and not due_missing(st["frame"]):
            st["map_wait"] += sim.now - st["wait_from"]
            st["waiting"] = None
            then()

    st["worker_b_started"] = False
    st["waiting"] = None
    st["service"] = []
    source_next()
    while sim.step():
        pass
    assert st["tracked"] == n, (order, st["tracked"])
    span = st["last_done"] - st["first_done"]
    return {"fps_streaming": (n - 1) / (span / 1e3), "ms_per_frame": span / (n - 1),
            "map_wait_ms_per_frame": st["map_wait"] / n,
            "service_ms_p50": float(np.percentile(st["service"], 50)), "service_ms_mean": float(np.mean(st["service"]))}


VARIANTS = {  # name: simulate() keyword arguments (s16: extract-ahead, "ahead", is the shipped order)
    "ahead": {"order": "ahead"},
    "ahead_mapping_nice5": {"order": "ahead", "mapping_nice": 5},
    "ahead_mapping_nice10": {"order": "ahead", "mapping_nice": 10},
    "ahead_worker_nice5": {"order": "ahead", "worker_nice": 5},
}


def report(rec: dict, enhance_ms: float) -> dict:
    res = {name: simulate(rec, enhance_ms=enhance_ms, **kw) for name, kw in VARIANTS.items()}
    for key, r in res.items():
        print(f"   {key:24s} {r['fps_streaming']:6.2f} fps  {r['ms_per_frame']:6.1f} ms/frame  "
              f"map wait {r['map_wait_ms_per_frame']:5.1f} ms/frame  tracking service p50 {r['service_ms_p50']:5.1f} "
              f"mean {r['service_ms_mean']:5.1f} ms")
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--reps", type=int, default=1, help="recordings (their CPU varies with the load)")
    ap.add_argument("--enhance-ms", type=float, default=1.3, help="enhancement actor CPU per frame (stats.json)")
    ap.add_argument("--replay", default=None, help="simulate the recordings of an earlier --out file again")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import os
    if args.replay:
        for rec in json.loads(Path(args.replay).read_text())["recordings"]:
            print(f"recording at load {rec['load']:.1f}:")
            report({"frames": rec["frames"], "lag": rec["lag"], "prefetch": rec["prefetch"]}, args.enhance_ms)
        return 0
    out = {"command": " ".join(sys.argv), "date": time.strftime("%Y-%m-%d %H:%M"), "recordings": []}
    for rep in range(args.reps):
        load = os.getloadavg()[0]
        rec = record(args.dataset, args.max_frames)
        cpu = {k: float(np.sum([f[k] for f in rec["frames"]]) / len(rec["frames"]))
               for k in ("decode", "pre", "before_stereo", "after", "worker_a", "worker_b", "ba")}
        print(f"rep {rep} load {load:.1f}: CPU ms/frame " + " ".join(f"{k} {v:.1f}" for k, v in cpu.items())
              + f" (sum {sum(cpu.values()) + args.enhance_ms:.1f} with enhancement)")
        res = report(rec, args.enhance_ms)
        out["recordings"].append({"load": load, "cpu_ms_per_frame": cpu, "lag": rec["lag"], "prefetch": rec["prefetch"],
                                  "keyframes": int(sum(f["keyframe"] for f in rec["frames"])), "model": res,
                                  "frames": rec["frames"]})
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
