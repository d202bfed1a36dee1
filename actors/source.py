"""Source actor: reads a dataset and writes stereo frames into the raw ring.

lockstep: frame i + 1 + ``lockstep_prefetch_frames`` is written only after
tracking reports frame i done (nothing is ever dropped, so every run is
identical); reading and enhancing the next frames overlaps tracking. realtime: frames are released at the
dataset's timestamps; a frame whose release time has already passed by more
than one period when it could be read is dropped and counted, as a camera
driver would.
"""
from __future__ import annotations

import threading
import time

from actors.runtime import Actor, ActorContext
from actors.schedstat import thread_report, thread_schedstat
from canopy.sources import open_source
from protocol.messages import EndOfStream, FrameDone, FrameHandle, Pause, Resume, Start
from shared.ring import FrameRing
from shared.types import StereoFrame


class SourceActor(Actor):
    name = "source"
    measure_messages = False

    def setup(self, ctx: ActorContext) -> None:
        c = self.config
        self.source = open_source(c["kind"], c["path"], max_frames=c.get("max_frames"))
        self.ring = FrameRing.attach(c["ring"])
        self.lockstep = c["clock"] == "lockstep"
        self.speed = float(c.get("realtime_speed", 1.0))
        self.stamps = self.source.timestamps
        self.period = 1.0 / max(self.source.rate_hz, 1e-6) / self.speed
        self.next_index = 0
        self.index_base = int(c.get("index_base", 0))
        self.started = False
        self.done = 0  # lockstep: frames tracking reported done
        self.prefetch = int(self.config.get("lockstep_prefetch_frames", 0))
        self.read_error: Exception | None = None  # lockstep: raised once the frames before it are done
        self.t0 = 0.0
        self.sent = 0
        self.paused_at: float | None = None  # remote pause (inspection request): no frame released
        # the threads' scheduler statistics from the first frame read on (stats.json "threads": the
        # source's CPU per frame, mostly PNG decoding, is taken from the same two cores as tracking's)
        self.sched_start: dict[int, tuple[int, int]] | None = None

    def on_control(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, Start):
            self.started = True
            self.t0 = time.monotonic()
        elif isinstance(msg, Pause) and self.paused_at is None:
            self.paused_at = time.monotonic()
        elif isinstance(msg, Resume) and self.paused_at is not None:
            if self.started:  # realtime: the dataset clock skips the pause instead of dropping its frames
                self.t0 += time.monotonic() - max(self.paused_at, self.t0)
            self.paused_at = None
        ctx.extra["paused"] = self.paused_at is not None

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, FrameDone):
            self.done += 1

    def _release_time(self, i: int) -> float:
        return self.t0 + (self.stamps[i] - self.stamps[0]) / self.speed

    def _finished(self) -> bool:
        return self.next_index > len(self.source)

    def next_tick_s(self) -> float | None:
        if not self.started or self._finished() or self.paused_at is not None:
            return None
        if self.lockstep:
            if self.read_error is not None:
                return None if self.done < self.sent else 0.0
            return None if self.sent - self.done > self.prefetch else 0.0
        if self.next_index >= len(self.source):
            return 0.0
        return self._release_time(self.next_index) - time.monotonic()

    def on_tick(self, ctx: ActorContext) -> float | None:
        if self.read_error is not None:  # every frame before the bad one has its pose now
            raise self.read_error
        n = len(self.source)
        if self.next_index >= n:
            ctx.send("enhancement", EndOfStream(n_frames=self.sent, sent_at=time.time()))
            ctx.extra["frames_sent"] = self.sent
            self.next_index = n + 1
            ctx.stop()
            return None
        i = self.next_index
        self.current_index = i  # a failure while reading names this frame, not the last acknowledged one
        self.next_index += 1
        if not self.lockstep and time.monotonic() - self._release_time(i) > self.period:
            ctx.dropped += 1  # too late to be useful: a live camera would have overwritten it
            return None
        if self.sched_start is None:
            self.sched_start = thread_schedstat()
        read_at = time.time()  # end-to-end latency (frame read -> pose published) starts here
        try:
            frame = self.source.frame(i)
        except Exception as exc:
            if not (self.lockstep and self.done < self.sent):
                raise
            # lockstep reads ahead of tracking: end the run only once the frames already read are
            # tracked, so the trajectory so far is the same as without reading ahead
            self.read_error = exc
            return None
        if self.index_base:  # a run extending a loaded map numbers its frames after the map's keyframes
            frame = StereoFrame(frame.index + self.index_base, frame.timestamp, frame.left, frame.right)
        slot, gen = self.ring.write(frame.index, frame.timestamp, [frame.left, frame.right])
        ctx.send("enhancement", FrameHandle(index=frame.index, timestamp=frame.timestamp, ring=self.ring.name,
                                            slot=slot, generation=gen, sent_at=time.time(), read_at=read_at))
        self.sent += 1
        ctx.extra["frames_sent"] = self.sent
        return 0.0

    def teardown(self, ctx: ActorContext) -> None:
        if self.sched_start is not None:
            ctx.extra["threads"] = thread_report(self.sched_start, thread_schedstat(),
                                                 {threading.get_native_id(): "source"}, self.sent)
        self.ring.close()
