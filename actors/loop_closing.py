"""Loop-closing actor: keyframe from local mapping → detection, verification, pose graph →
correction back to local mapping (which forwards the corrected map to tracking).

A thin loop around ``canopy.loop.worker.LoopWorker``, which owns the ``LoopCloser`` and does all
of its work in a forked worker process niced to ``loop.niceness`` (19), with the full bundle
adjustment (AGRI §3.4.2) after a loop in a child of it niced alike; this actor only hands
keyframes over and sends what the worker produces, at normal priority, so its messages and the
heartbeat are never starved when tracking and local mapping keep the cores busy (issue 10: the
loop closer never delays tracking). A process rather than a thread: a niced thread holding the
GIL starves the actor's thread on a loaded machine (``canopy.loop.worker``). Every keyframe is answered with a ``LoopResult`` (closed or
not); closed loops also go to the supervisor, which counts them in the outputs. Tracking never
waits on this actor. The service time in stats.json is the hand-over; the worker's own time per
keyframe is ``extra.step_ms_p50`` / ``step_ms_p95``.

At the end of the stream the worker and a running BA go back to normal priority, the remaining
keyframes are taken and the BA is waited for (telling local mapping each second that the loop
closer is still at work) before the end is passed on, so the final map carries it.
"""
from __future__ import annotations

import queue
import threading
import time

from actors.runtime import Actor, ActorContext
from actors.schedstat import thread_report, thread_schedstat
from canopy.loop.closer import LoopCloser
from canopy.loop.vocabulary import load_vocabulary
from canopy.loop.worker import LoopWorker, place_keyframe  # noqa: F401  (place_keyframe: used by tests)
from protocol.messages import EndOfStream, LoopKeyframe, LoopResult

OUTBOX_POLL_S = 0.05   # how often this thread looks for a thread worker's answers (no fd to wait on)
KEEPALIVE_S = 1.0      # at the end of the stream: "still at work" to local mapping this often


class LoopClosingActor(Actor):
    name = "loop_closing"
    # With a worker process the run loop wakes on the inbox, control and the worker's outbox pipe
    # (``wait_fds``) and for the heartbeat, so idle time is slept through instead of polled at 20 Hz.
    idle_wait_s = 1.0

    def setup(self, ctx: ActorContext) -> None:
        params = self.config["params"]
        self.vocabulary = load_vocabulary(params.vocabulary)
        if self.config.get("sensor", "stereo") == "mono":  # Sim(3) verification and pose graph
            from canopy.loop.mono import MonoLoopCloser
            self.closer = MonoLoopCloser(self.config["calib"], params, self.vocabulary, self.config.get("mono"))
        else:
            self.closer = LoopCloser(self.config["calib"], params, self.vocabulary)
        if self.config.get("load_map"):  # --load-map (extending): loops can close against the loaded keyframes
            from canopy.loop.map_io import load_map, seed_loop_closer
            ctx.extra["loaded_keyframes"] = seed_loop_closer(self.closer, load_map(self.config["load_map"],
                                                                                   self.config["calib"]))
        ctx.extra.update({"loops": 0, "vocabulary": getattr(self.vocabulary, "name", "")})
        self.worker = LoopWorker(self.closer, self.vocabulary, niceness=int(getattr(params, "niceness", 0)),
                                 idle=bool(getattr(params, "sched_idle", True)))
        self.worker.start()
        # this process's threads from the first keyframe on (stats.json "threads": the hand-over and
        # relay CPU per frame; the worker process's own CPU is extra.step_cpu_s)
        self.sched_start: dict[int, tuple[int, int]] | None = None
        self.n_frames = 0

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, LoopKeyframe):
            if self.sched_start is None:
                self.sched_start = thread_schedstat()
            self.worker.submit(msg)   # the hand-over: the work happens in the worker thread
        elif isinstance(msg, EndOfStream):
            self.n_frames = int(msg.n_frames)
            self.worker.finish()
            self._wait_for_worker(ctx)
            ctx.send("local_mapping", EndOfStream(n_frames=msg.n_frames, sent_at=time.time()), block=False)
            ctx.stop()

    def wait_fds(self) -> list[int]:
        fd = self.worker.outbox_fd()
        return [] if fd is None else [fd]

    def next_tick_s(self) -> float | None:
        if not self.worker.outbox.empty():
            return 0.0
        return None if self.worker.outbox_fd() is not None else OUTBOX_POLL_S

    def on_tick(self, ctx: ActorContext) -> float | None:
        self._flush(ctx)
        return None

    def _flush(self, ctx: ActorContext, wait_s: float = 0.0) -> bool:
        """Send what the worker produced; True once it is done."""
        done = False
        while True:
            try:
                item = self.worker.outbox.get(timeout=wait_s) if wait_s > 0 else self.worker.outbox.get_nowait()
            except queue.Empty:
                return done
            wait_s = 0.0
            kind = item[0]
            if kind == "send":
                ctx.send(item[1], item[2])
            elif kind == "publish":
                ctx.publish(item[1])
            elif kind == "extra":
                ctx.extra.update(item[1])
            elif kind == "error":
                raise RuntimeError(f"loop closer worker failed: {item[1]}")
            elif kind == "done":
                done = True

    def _wait_for_worker(self, ctx: ActorContext) -> None:
        """End of the stream: the worker takes the remaining keyframes and waits for the full BA;
        meanwhile local mapping hears each second that the loop closer is still at work."""
        last = 0.0
        while True:
            if self._flush(ctx, wait_s=0.2):
                return
            if not self.worker.alive() and self.worker.outbox.empty():
                return
            if time.monotonic() - last >= KEEPALIVE_S:
                last = time.monotonic()
                ctx.heartbeat()
                ctx.send("local_mapping", LoopResult(keyframe_index=-1, loops=int(ctx.extra.get("loops", 0)),
                                                     sent_at=time.time()), block=False)

    def teardown(self, ctx: ActorContext) -> None:
        if self.sched_start is not None:   # per frame of the stream (per keyframe if it never ended)
            ctx.extra["threads"] = thread_report(self.sched_start, thread_schedstat(),
                                                 {threading.get_native_id(): "loop_closing"},
                                                 self.n_frames or int(ctx.extra.get("keyframes", 0)))
        self.worker.stop()
