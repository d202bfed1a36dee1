"""Enhancement actor: raw ring slot → enhanced ring slot.

It owns its output ring, so tracking always reads images this actor wrote.
Both images of a pair get the same treatment (``auto`` decides on the left
image and applies that decision to the right one), otherwise stereo matching
would compare differently processed images.
"""
from __future__ import annotations

import time

import numpy as np

from actors.runtime import Actor, ActorContext
from canopy.enhance import make_enhancer
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

    def setup(self, ctx: ActorContext) -> None:
        self.in_ring = FrameRing.attach(self.config["in_ring"])
        self.out_ring = FrameRing.attach(self.config["out_ring"])
        self.enhancer = make_enhancer(self.config["params"])
        self.lockstep = self.config["clock"] == "lockstep"
        self.methods: dict[str, int] = {}

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, EndOfStream):
            ctx.send("tracking", EndOfStream(n_frames=msg.n_frames, sent_at=time.time()))
            ctx.stop()
            return
        if not isinstance(msg, FrameHandle):
            return
        if not self.lockstep:
            # Fell behind: keep only the newest frame, count the rest as dropped.
            for newer in ctx.drain_inbox():
                if isinstance(newer, FrameHandle):
                    ctx.dropped += 1
                    msg = newer
                elif isinstance(newer, EndOfStream):
                    self.on_message(msg, ctx)
                    self.on_message(newer, ctx)
                    return
        try:
            index, stamp, (left, right) = self.in_ring.read(msg.slot, msg.generation)
        except SlotOverwritten:
            ctx.dropped += 1
            return
        lay = self.out_ring.layout
        t0 = time.perf_counter()
        left_e, info = self.enhancer(left)
        right_e, _ = self.enhancer(right, method=info.get("method"))
        enhance_ms = (time.perf_counter() - t0) * 1e3
        check_pair(left_e, right_e, lay.height, lay.width, index)
        slot, gen = self.out_ring.write(index, stamp, [left_e, right_e])
        method = info.get("method", "none")
        self.methods[method] = self.methods.get(method, 0) + 1
        ctx.extra["methods"] = dict(self.methods)
        info = {k: v for k, v in info.items() if isinstance(v, (int, float, str, bool))}
        info["enhance_ms"] = enhance_ms
        ctx.send("tracking", FrameHandle(index=index, timestamp=stamp, ring=self.out_ring.name, slot=slot,
                                         generation=gen, sent_at=time.time(), info=info))

    def teardown(self, ctx: ActorContext) -> None:
        self.in_ring.close()
        self.out_ring.close()
