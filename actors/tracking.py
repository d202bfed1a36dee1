"""Tracking actor: enhanced frame → pose (and sometimes a keyframe).

A thin loop around ``canopy.frontend.Tracker``. It keeps the tracker's
local-map view fresh with the updates local mapping sends back; in lockstep
the update answering the keyframe made at frame i is applied before frame
i + 1 + ``map_update_lag_frames`` (waited for if it is not there yet, held if
it came early: ``canopy.pipeline.MapUpdateSchedule``), so tracking overlaps
local BA and runs are still repeatable. Each frame's pose goes to the supervisor together with
its pose relative to the reference keyframe, so later corrections of that
keyframe carry over to the frame.
"""
from __future__ import annotations

import sys
import threading
import time

import cv2
import numpy as np

from actors.backlog import FrameBacklog, max_frame_age
from actors.runtime import Actor, ActorContext
from actors.schedstat import thread_report, thread_schedstat
from canopy.enhance import tracking_fast_arguments
from canopy.frontend import Tracker
from canopy.pipeline import MapUpdateSchedule, effective_map_update_lag
from protocol.messages import EndOfStream, FrameDone, FrameHandle, FramePose, LocalMapUpdate
from shared.errors import CanopyError
from shared.ring import FrameRing, SlotOverwritten
from shared.types import StereoFrame

# AFE's adaptive FAST threshold belongs with the enhancement it was designed for.
ADAPTIVE_FAST_METHODS = ("afe", "auto")


class TrackingActor(Actor):
    name = "tracking"
    measure_messages = False  # frames are timed when taken from the backlog

    def setup(self, ctx: ActorContext) -> None:
        c = self.config
        self.ring = FrameRing.attach(c["ring"])
        # OpenCV calls run on their caller (tracking, its worker): no pool thread to wait for
        # (TrackingParams.opencv_threads)
        n_cv = int(getattr(c["params"], "opencv_threads", 0))
        if n_cv > 0:
            cv2.setNumThreads(n_cv)
        # the GIL's hand-over interval between the tracking thread and its worker (TrackingParams.switch_interval_ms)
        switch_ms = float(getattr(c["params"], "switch_interval_ms", 0.0))
        if switch_ms > 0:
            sys.setswitchinterval(switch_ms / 1e3)
        if c.get("sensor", "stereo") == "mono":
            from canopy.mono import MonoTracker
            self.tracker = MonoTracker(c["calib"], c["params"], c.get("mono"))
        else:
            self.tracker = Tracker(c["calib"], c["params"])
            self._attach_place_memory(c)
        self.lockstep = c["clock"] == "lockstep"
        self.backlog = FrameBacklog(max_frame_age(c["clock"], c["frame_period_s"], c["max_lag_frames"]))
        self.wait_s = float(c.get("lockstep_wait_s", 60.0))
        lag = effective_map_update_lag(int(c.get("map_update_lag_frames", 0)), c["params"],
                                       c.get("sensor", "stereo"))
        self.schedule = MapUpdateSchedule(lag) if self.lockstep else None
        # lockstep: a frame's features before waiting for the map updates due at it (runtime.lockstep_extract_ahead)
        self.extract_ahead = bool(c.get("extract_ahead", True)) and hasattr(self.tracker, "extract")
        enh = c.get("enhancement")
        self.adaptive_fast = bool(enh is not None and getattr(enh, "adaptive_fast", False)
                                  and enh.method in ADAPTIVE_FAST_METHODS)
        self.enhancement = enh
        self.hands_sensor_sigma = isinstance(self.tracker, Tracker)  # the mono tracker takes no sensor sigma
        self.n_features = int(getattr(c["params"], "n_features", 0))
        self.counts = {"ok": 0, "lost": 0, "init": 0, "predicted": 0, "keyframes": 0}
        self.loop_epoch = 0  # loop corrections received from local mapping
        # per-stage tracking-thread CPU ms of every frame (<stage>_cpu timings) for stats.json, and
        # the threads' scheduler statistics from the first frame on (start-up excluded)
        self.stage_cpu: dict[str, list[float]] = {}
        self.sched_start: dict[int, tuple[int, int]] | None = None
        self.sched_start_wall = 0.0
        self.n_tracked = 0
        # where the tracking thread's wall time goes beyond its CPU and run-queue wait, per frame:
        # waiting for a lockstep map update before the frame, waiting for the worker's stereo matches
        # (the tracker's "stereo" stage, wall), and the rest of the blocked time (GIL, OpenCV's pool)
        self.waits: dict[str, list[float]] = {"map_update": [], "stereo": []}

    def _attach_place_memory(self, c: dict) -> None:
        """Relocalisation by database query (canopy.loop.relocalise): in a map loaded with
        --load-map, or, with loop closing on, in this run's own keyframes after a long gap."""
        loop, map_path = c.get("loop"), c.get("load_map")
        if not map_path and (loop is None or not loop.enabled):
            return
        from canopy.loop.params import LoopParams
        from canopy.loop.relocalise import PlaceMemory
        from canopy.loop.vocabulary import load_vocabulary

        params = loop or LoopParams()
        vocabulary = load_vocabulary(params.vocabulary)
        if map_path:
            from canopy.loop.map_io import load_map
            memory = PlaceMemory.from_map(load_map(map_path, c["calib"]), params, vocabulary)
            localize = bool(c.get("localize"))
            self.tracker.attach_place_memory(memory, live=not localize, loaded=True, localize=localize)
        else:
            self.tracker.attach_place_memory(PlaceMemory(c["calib"], params, vocabulary), live=True)

    def _apply_update(self, update: LocalMapUpdate) -> None:
        self.tracker.apply_map_update(update)
        self.loop_epoch = max(self.loop_epoch, int(update.loop_epoch))

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, LocalMapUpdate):
            if self.schedule is not None:  # lockstep: applied at its fixed frame, never as it comes
                self.schedule.hold(msg)
            else:
                self._apply_update(msg)
        else:
            self.backlog.push(msg)

    def next_tick_s(self) -> float | None:
        return 0.0 if self.backlog.has_work() else None

    def on_tick(self, ctx: ActorContext) -> float | None:
        # Map updates that arrived meanwhile go in before the next frame is tracked.
        for msg in ctx.drain_inbox():
            self.on_message(msg, ctx)
        handle, dropped = self.backlog.pop()
        ctx.dropped += dropped
        if handle is None:
            ctx.send("local_mapping", EndOfStream(n_frames=self.backlog.end.n_frames, sent_at=time.time()))
            if ctx.has_output("recorder"):  # last on this pipe: the recorder has everything before it
                ctx.send("recorder", EndOfStream(n_frames=self.backlog.end.n_frames, sent_at=time.time()))
            ctx.stop()
            return None
        try:
            index, stamp, (left, right) = self.ring.read(handle.slot, handle.generation)
        except SlotOverwritten:
            ctx.dropped += 1
        else:
            frame = StereoFrame(index, stamp, left, right)
            if self.schedule is not None and self.extract_ahead:
                # the frame's ORB and stereo matches need no map: computed while local mapping may
                # still be adjusting the keyframe whose update is due now (the same result)
                self._start_sched()
                extracted = self.tracker.extract(frame, **self._frame_arguments(frame, handle))
                t0 = time.perf_counter()
                self._apply_due_updates(index, ctx)
                self._track(frame, handle, ctx, extracted, time.perf_counter() - t0)
            else:
                if self.schedule is not None:
                    self._apply_due_updates(index, ctx)
                self._track(frame, handle, ctx)
        return handle.sent_at

    def _start_sched(self) -> None:
        if self.sched_start is None:  # the threads' statistics from the first frame on
            self.sched_start = thread_schedstat()
            self.sched_start_wall = time.perf_counter()

    def _frame_arguments(self, frame: StereoFrame, handle: FrameHandle) -> dict:
        """The stereo tracker's per-frame arguments from the enhancement: the FAST rule's, and the
        enhancement's own noise sigma of the pair (``handle.info["noise_sigma"]``, 0 on frames it did not
        denoise; absent from a handle without enhancement info), which gates the stereo fill-in on
        enhanced frames (``canopy.frontend.stereo_fill.sensor_fill_open``): the tracker sees only the
        enhanced pair, whose own residual noise tells texture from sensor noise far less cleanly."""
        kw = self._fast_arguments(frame, handle)
        sigma = (handle.info or {}).get("noise_sigma")
        if self.hands_sensor_sigma and sigma is not None:
            kw["sensor_sigma"] = float(sigma)
        return kw

    def _fast_arguments(self, frame: StereoFrame, handle: FrameHandle) -> dict:
        # AFE Eq. 18, and Eq. 19 when too few corners result; only on frames the enhancement changed
        # (auto's "none" frames keep the fixed threshold, so auto costs nothing on clean data)
        # (rule: canopy.enhance.fast.tracking_fast_arguments; denoised dark frames fill the feature budget)
        if not self.adaptive_fast:
            return {}
        return tracking_fast_arguments(frame.left, (handle.info or {}).get("method", "none"), self.enhancement,
                                       self.n_features)

    def _track(self, frame: StereoFrame, handle: FrameHandle, ctx: ActorContext, extracted=None,
               paused_s: float = 0.0) -> None:
        """Track ``frame`` (or finish it: ``extracted`` from ``Tracker.extract``, ``paused_s`` spent
        since waiting for map updates) and send its pose, keyframe and acknowledgement."""
        self._start_sched()
        if extracted is not None:
            res = self.tracker.track_extracted(extracted, paused_s)
        else:
            res = self.tracker.track(frame, **self._frame_arguments(frame, handle))
        self.counts[res.status] = self.counts.get(res.status, 0) + 1
        self.n_tracked += 1
        for key, ms in res.timings.items():
            if key.endswith("_cpu"):
                self.stage_cpu.setdefault(key[:-4], []).append(float(ms))
        self.waits["stereo"].append(float(res.timings.get("stereo", 0.0)))
        if res.lost_reason:
            self.counts[f"lost_reason_{res.lost_reason}"] = self.counts.get(f"lost_reason_{res.lost_reason}", 0) + 1
        # a monocular initialisation hands over two keyframes (reference and current)
        keyframes = getattr(res, "keyframes", None) or ([res.keyframe] if res.is_keyframe else [])
        for kf in keyframes:
            self.counts["keyframes"] += 1
            kf.loop_epoch = self.loop_epoch
            ctx.send("local_mapping", kf)
            if self.schedule is not None:
                self.schedule.keyframe_sent(kf.index, res.index)
        # Lost frames (no reference) keep their absolute pose: ref_keyframe = -1.
        ref = res.reference_kf_index if res.T_ref_cam is not None else -1
        T_ref_cam = res.T_ref_cam if res.T_ref_cam is not None else np.eye(4)
        timings = {k: float(v) for k, v in res.timings.items()}
        if "enhance_ms" in handle.info:
            timings["enhance"] = float(handle.info["enhance_ms"])
        pose = FramePose(index=res.index, timestamp=res.timestamp, T_world_cam=res.T_world_cam,
                         status=res.status, n_inliers=int(res.n_inliers), n_matches=int(res.n_matches),
                         is_keyframe=bool(res.is_keyframe), ref_keyframe=int(ref),
                         T_ref_cam=T_ref_cam, timings_ms=timings, sent_at=time.time(),
                         enhancement={k: v for k, v in handle.info.items() if k != "enhance_ms"},
                         n_lines=int(res.n_lines), n_line_inliers=int(res.n_line_inliers),
                         lost_reason=res.lost_reason, frame_read_at=handle.read_at)
        for reason, n in res.line_rejected.items():  # degenerate segments, counted never fatal
            self.counts[f"lines_rejected_{reason}"] = self.counts.get(f"lines_rejected_{reason}", 0) + n
        ctx.publish(pose)
        if ctx.has_output("recorder"):  # never block tracking on the recorder
            ctx.send("recorder", pose, block=False)
            ctx.send("recorder", handle, block=False)
        # wall clock of the first and last tracked frame: throughput without process start-up
        ctx.extra.setdefault("first_frame_done_at", time.time())
        ctx.extra["last_frame_done_at"] = time.time()
        ctx.extra.update(self.counts)
        if self.lockstep:
            ctx.send("source", FrameDone(index=res.index, sent_at=time.time()))

    def _apply_due_updates(self, frame_index: int, ctx: ActorContext) -> None:
        """Lockstep: apply the map updates due before ``frame_index``, waiting for any that has
        not arrived; frames and the end of stream arriving meanwhile queue in the backlog."""
        t0 = time.perf_counter()
        deadline = time.monotonic() + self.wait_s
        while (kf_index := self.schedule.missing(frame_index)) is not None:
            if time.monotonic() >= deadline:
                raise CanopyError(f"tracking: no map update for keyframe {kf_index} within {self.wait_s:.0f} s")
            msg = ctx.recv_inbox(100)
            if msg is not None:
                self.on_message(msg, ctx)
        if self.sched_start is not None:  # from the first frame on, as the thread statistics
            self.waits["map_update"].append((time.perf_counter() - t0) * 1e3)
        for update in self.schedule.take_due(frame_index):
            self._apply_update(update)

    def teardown(self, ctx: ActorContext) -> None:
        self.ring.close()
        # stats.json: where tracking's time went (CPU of each stage on the tracking thread, p50) and
        # whether its threads waited for a core (run-queue wait, actors/schedstat.py)
        ctx.extra["stage_ms_p50"] = {k: round(float(np.percentile(v, 50)), 3) for k, v in self.stage_cpu.items()}
        if self.sched_start is not None:
            names = {threading.get_native_id(): "tracking"}
            worker = getattr(self.tracker, "worker_thread_id", lambda: None)()
            if worker is not None:
                names[worker] = "tracking_worker"
            ctx.extra["threads"] = thread_report(self.sched_start, thread_schedstat(), names, self.n_tracked)
            # the tracking thread's wall time since the first frame minus its CPU and run-queue wait:
            # the time it slept (waits above, the GIL, OpenCV's thread pool, the next frame's arrival)
            me = ctx.extra["threads"].get("tracking")
            if me is not None and self.n_tracked:
                wall_ms = (time.perf_counter() - self.sched_start_wall) * 1e3 / self.n_tracked
                me["blocked_ms_per_frame"] = round(wall_ms - me["cpu_ms_per_frame"] - me["runqueue_wait_ms_per_frame"], 3)
            ctx.extra["wait_ms"] = {name: {"p50": round(float(np.percentile(v, 50)), 3),
                                           "mean": round(float(np.mean(v)), 3)}
                                    for name, v in self.waits.items() if v}
