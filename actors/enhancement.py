"""Enhancement actor: raw ring slot → enhanced ring slot.

It owns its output ring, so tracking always reads images this actor wrote.
Both images of a pair get the same treatment (``auto`` decides on the left
image and applies that decision, with the left image's exposure γ and noise
σ, to the right one), otherwise stereo matching would compare differently
processed images; ``canopy.enhance.pair.PairEnhancer`` does this, with the
two images' pixel work on two threads when ``pair_threads`` is 2.
"""
from __future__ import annotations

import threading
import time

import numpy as np

from actors.backlog import FrameBacklog, max_frame_age
from actors.runtime import Actor, ActorContext
from actors.schedstat import thread_report, thread_schedstat
from canopy.enhance.pair import PairEnhancer
from protocol.messages import EndOfStream, FrameHandle
from shared.errors import InputError
from shared.ring import FrameRing, SlotOverwritten


def check_pair(left: np.ndarray, right: np.ndarray, height: int, width: int, index: int) -> None:
    """A frame of the wrong size or type must fail loudly, naming the frame."""
    for side, img in (("left", left), ("right", right)):
        if img.dtype != np.uint8 or img.shape != (height, width):
            raise InputError(f"frame {index} ({side})",
                             f"image is {img.dtype} {img.shape}, expected uint8 {(height, width)}")


class EnhancementActor(Actor):
    name = "enhancement"
    measure_messages = False  # frames are timed when taken from the backlog

    def setup(self, ctx: ActorContext) -> None:
        self.in_ring = FrameRing.attach(self.config["in_ring"])
        self.out_ring = FrameRing.attach(self.config["out_ring"])
        self.enhancer = PairEnhancer(self.config["params"])  # two threads if params.pair_threads == 2
        self.backlog = FrameBacklog(max_frame_age(self.config["clock"], self.config["frame_period_s"],
                                                  self.config["max_lag_frames"]))
        self.methods: dict[str, int] = {}
        # the threads' scheduler statistics from the first frame on (stats.json "threads": with
        # ``pair_threads`` 2 the right image's pixel work is on a pool thread, counted as "other")
        self.sched_start: dict[int, tuple[int, int]] | None = None
        self.n_frames = 0

    def on_message(self, msg, ctx: ActorContext) -> None:
        self.backlog.push(msg)

    def next_tick_s(self) -> float | None:
        return 0.0 if self.backlog.has_work() else None

    def on_tick(self, ctx: ActorContext) -> float | None:
        if self.sched_start is None:
            self.sched_start = thread_schedstat()
        handle, dropped = self.backlog.pop()
        ctx.dropped += dropped
        if handle is None:
            ctx.send("tracking", EndOfStream(n_frames=self.backlog.end.n_frames, sent_at=time.time()))
            ctx.stop()
            return None
        # The raw slot is read in place (no copy): when ``auto`` decides "none" the enhancer
        # returns its inputs and the one copy is the write into our ring. The source may overwrite
        # the slot meanwhile (a reader a whole ring behind): checked once the pixels are used, the
        # frame then counts as dropped, as a torn copy did (shared.ring's seqlock).
        try:
            index, stamp, (left, right) = self.in_ring.view(handle.slot, handle.generation)
        except SlotOverwritten:
            ctx.dropped += 1
            return handle.sent_at
        lay = self.out_ring.layout
        check_pair(left, right, lay.height, lay.width, index)
        t0 = time.perf_counter()
        left_e, right_e, info = self.enhancer(left, right)
        enhance_ms = (time.perf_counter() - t0) * 1e3
        check_pair(left_e, right_e, lay.height, lay.width, index)
        slot, gen = self.out_ring.write(index, stamp, [left_e, right_e])
        if not self.in_ring.holds(handle.slot, handle.generation):
            ctx.dropped += 1   # the written slot is never announced, so nobody reads it
            return handle.sent_at
        self.methods[info["method"]] = self.methods.get(info["method"], 0) + 1
        self.n_frames += 1
        ctx.extra["methods"] = dict(self.methods)
        info = {k: v for k, v in info.items() if isinstance(v, (int, float, str, bool))}
        info["enhance_ms"] = enhance_ms
        ctx.send("tracking", FrameHandle(index=index, timestamp=stamp, ring=self.out_ring.name, slot=slot,
                                         generation=gen, sent_at=time.time(), info=info,
                                         read_at=handle.read_at))
        return handle.sent_at

    def teardown(self, ctx: ActorContext) -> None:
        if self.sched_start is not None:
            ctx.extra["threads"] = thread_report(self.sched_start, thread_schedstat(),
                                                 {threading.get_native_id(): "enhancement"}, self.n_frames)
        if getattr(self, "enhancer", None) is not None:
            self.enhancer.close()
        self.in_ring.close()
        self.out_ring.close()
