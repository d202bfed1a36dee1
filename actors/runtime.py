"""The one loop every actor runs (Kimera-VIO's PipelineModule idea).

An actor is a small class with ``setup`` / ``on_message`` / ``on_tick`` /
``teardown``; the algorithm lives elsewhere and ``on_message`` is its
``spin_once``. Everything else lives here, once: ZeroMQ sockets, timing of
every call (service time and queue wait), CPU and RSS sampling, a stats
message every second that doubles as the heartbeat, orderly shutdown, and
turning an exception into an ``ActorError`` for the supervisor instead of a
silent death.

Sockets (all ipc:// on one host):
- ``inbox``  PULL, bound by the actor: data messages from upstream actors.
- ``control`` PULL, bound by the actor: Start / Shutdown from the supervisor.
- ``events`` PUSH, connected to the supervisor: ready, stats, results, errors.
- one PUSH per downstream actor, connected to that actor's inbox.
PUSH/PULL (not PUB/SUB) so no message is lost to a slow joiner.
"""
from __future__ import annotations

import importlib
import os
import signal
import sys
import time
import traceback
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import psutil
import zmq

from protocol.codec import decode, encode
from protocol.messages import ActorError, ActorReady, ActorStats, Shutdown
from shared.errors import CanopyError, InputWarning

STATS_PERIOD_S = 1.0


@dataclass
class ActorSpec:
    """Everything a child process needs to become an actor (picklable)."""
    name: str
    factory: str                 # "module:Class"
    config: dict
    inbox: str                   # endpoint this actor binds for data
    control: str                 # endpoint this actor binds for control
    events: str                  # supervisor's endpoint
    outputs: dict = field(default_factory=dict)  # downstream name -> inbox endpoint
    seed: int = 0


class ActorContext:
    """What an actor may do to the outside world."""

    def __init__(self, spec: ActorSpec, zctx: zmq.Context):
        self.spec = spec
        self.name = spec.name
        self._zctx = zctx
        self._out: dict[str, zmq.Socket] = {}
        for target, endpoint in spec.outputs.items():
            sock = zctx.socket(zmq.PUSH)
            sock.setsockopt(zmq.LINGER, 1000)
            sock.connect(endpoint)
            self._out[target] = sock
        self._events = zctx.socket(zmq.PUSH)
        self._events.setsockopt(zmq.LINGER, 2000)
        self._events.connect(spec.events)
        self.inbox = zctx.socket(zmq.PULL)
        self.inbox.bind(spec.inbox)
        self.control = zctx.socket(zmq.PULL)
        self.control.bind(spec.control)
        self.dropped = 0
        self.blocked_s = 0.0  # time spent waiting on another actor inside a call; not service time
        self.extra: dict[str, Any] = {}
        self.stop_requested = False
        # Set by the run loop: sends a heartbeat (stats) when one is due, so an actor blocked
        # waiting on another one keeps saying it is alive and the supervisor blames the right one.
        self.heartbeat = lambda: None

    def send(self, target: str, msg: Any, block: bool = True) -> bool:
        """Send to a downstream actor. ``block=False`` gives up (returns False)
        when the peer is gone or its queue is full, e.g. after it finished."""
        sock = self._out.get(target)
        if sock is None:
            raise CanopyError(f"actor {self.name!r} has no output named {target!r}")
        if getattr(msg, "sent_at", None) == 0.0:
            msg.sent_at = time.time()  # the receiver's queue wait starts now (issue 11: keyframes had none)
        try:
            sock.send(encode(msg), 0 if block else zmq.NOBLOCK)
        except zmq.Again:
            return False
        return True

    def has_output(self, target: str) -> bool:
        return target in self._out

    def publish(self, msg: Any) -> None:
        """Send to the supervisor (results, stats, errors)."""
        self._events.send(encode(msg))

    def recv_inbox(self, timeout_ms: int) -> Any | None:
        """Blocking receive on the inbox for actors that must wait (lockstep).
        The wait is booked as blocked time, not as this actor's service time."""
        t0 = time.perf_counter()
        try:
            deadline = t0 + timeout_ms / 1e3
            while True:
                left_ms = max(0, int((deadline - time.perf_counter()) * 1e3))
                if self.inbox.poll(min(left_ms, int(STATS_PERIOD_S * 1e3))):
                    return decode(self.inbox.recv())
                self.heartbeat()
                if left_ms == 0 or time.perf_counter() >= deadline:
                    return None
        finally:
            self.blocked_s += time.perf_counter() - t0

    def drain_inbox(self) -> list[Any]:
        out = []
        while self.inbox.poll(0):
            out.append(decode(self.inbox.recv()))
        return out

    def stop(self) -> None:
        self.stop_requested = True

    def close(self) -> None:
        for sock in [*self._out.values(), self._events, self.inbox, self.control]:
            sock.close()


class Actor:
    """Base class: override what you need. ``on_message`` is the spin_once."""

    name = "actor"
    # False for actors whose messages only queue work (frames go to a backlog,
    # acknowledgements to the source): their service time is measured in on_tick.
    measure_messages = True
    # Longest wait for a message when ``next_tick_s`` is None; the run loop still wakes when the
    # stats message (the heartbeat) is due. Actors that only wait on their inbox and ``wait_fds``
    # may raise it to sleep through idle time (each wake-up costs CPU on a loaded machine).
    idle_wait_s = 0.1

    def __init__(self, config: dict, seed: int = 0):
        self.config = config
        self.seed = seed

    def setup(self, ctx: ActorContext) -> None:
        pass

    def on_message(self, msg: Any, ctx: ActorContext) -> None:
        pass

    def on_control(self, msg: Any, ctx: ActorContext) -> None:
        pass

    def next_tick_s(self) -> float | None:
        """Seconds until ``on_tick`` wants to run; None = only on messages."""
        return None

    def wait_fds(self) -> list[int]:
        """File descriptors (besides the inbox and control sockets) whose readiness should wake
        the run loop, e.g. a worker process's result pipe: waits then block on them instead of
        polling. Asked once, after ``setup``."""
        return []

    def on_tick(self, ctx: ActorContext) -> float | None:
        """Do due work. Return None if nothing was done, else the ``sent_at`` of
        the item handled (0.0 if it had none) so it is timed like a message."""
        return None

    def teardown(self, ctx: ActorContext) -> None:
        pass


class _Meter:
    """Per-message timings since the last stats message, plus process load."""

    def __init__(self):
        self.proc = psutil.Process()
        self.proc.cpu_percent(None)
        self.service: list[float] = []
        self.queue: list[float] = []
        self.messages = 0
        self.seq = 0
        self.peak_rss = 0.0
        self.last = time.monotonic()

    def record(self, service_ms: float, queue_ms: float | None) -> None:
        self.messages += 1
        self.service.append(service_ms)
        if queue_ms is not None:
            self.queue.append(max(queue_ms, 0.0))

    def stats(self, name: str, ctx: ActorContext, final: bool = False) -> ActorStats:
        rss = self.proc.memory_info().rss / 2**20
        self.peak_rss = max(self.peak_rss, rss)
        msg = ActorStats(actor=name, pid=os.getpid(), seq=self.seq, messages=self.messages,
                         dropped=ctx.dropped, service_ms=np.asarray(self.service, np.float32),
                         queue_ms=np.asarray(self.queue, np.float32),
                         cpu_percent=float(self.proc.cpu_percent(None)), rss_mb=rss,
                         peak_rss_mb=self.peak_rss, extra=dict(ctx.extra), final=final)
        self.seq += 1
        self.service, self.queue = [], []
        self.last = time.monotonic()
        return msg


def _load_factory(path: str):
    module, _, cls = path.partition(":")
    return getattr(importlib.import_module(module), cls)


# mallopt parameters (glibc malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_memory(mb: int) -> bool:
    """Keep freed heap blocks up to ``mb`` MB in this process (glibc ``mallopt``): allocations below
    that come from the heap, not from a fresh ``mmap``, and the heap's top is trimmed only past 4x
    that, so a frame's temporaries reuse pages that are already mapped instead of faulting them in.
    The fixed thresholds also stop glibc's dynamic ones from moving. False where the C library is not
    glibc (the call is then a no-op) or ``mb`` is 0."""
    if mb <= 0 or not sys.platform.startswith("linux"):
        return False
    import ctypes
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):   # musl and others: no mallopt
        return False
    size = int(mb) << 20
    return bool(mallopt(_M_MMAP_THRESHOLD, size)) and bool(mallopt(_M_TRIM_THRESHOLD, 4 * size))


def actor_main(spec: ActorSpec) -> None:
    """Entry point of an actor process."""
    # Ctrl-C reaches the whole process group; only the supervisor decides.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The launcher opened the dataset first and already printed its input warnings once.
    warnings.simplefilter("ignore", InputWarning)
    parent = os.getppid()
    zctx = zmq.Context()
    ctx = None
    actor = None
    exit_code = 0
    current_index = -1
    try:
        ctx = ActorContext(spec, zctx)
        ctx.extra["malloc_keep_mb"] = int(spec.config.get("malloc_keep_mb", 0)) \
            if keep_freed_memory(int(spec.config.get("malloc_keep_mb", 0))) else 0
        if int(spec.config.get("niceness", 0)) > 0:  # a lower CPU priority (runtime.*_niceness)
            os.nice(int(spec.config["niceness"]))
        ctx.extra["niceness"] = os.nice(0)  # as the process runs (stats.json), whatever set it
        actor = _load_factory(spec.factory)(spec.config, seed=spec.seed)
        actor.name = spec.name
        actor.setup(ctx)
        ctx.publish(ActorReady(actor=spec.name, pid=os.getpid()))
        meter = _Meter()

        def heartbeat() -> None:
            if time.monotonic() - meter.last >= STATS_PERIOD_S:
                ctx.publish(meter.stats(spec.name, ctx))

        ctx.heartbeat = heartbeat
        poller = zmq.Poller()
        poller.register(ctx.control, zmq.POLLIN)
        poller.register(ctx.inbox, zmq.POLLIN)
        for fd in actor.wait_fds():
            poller.register(fd, zmq.POLLIN)
        idle_ms = max(1, int(actor.idle_wait_s * 1000))
        while not ctx.stop_requested:
            tick = actor.next_tick_s()
            if tick is None:   # no later than the next stats message (the heartbeat)
                stats_due_ms = int((meter.last + STATS_PERIOD_S - time.monotonic()) * 1000) + 1
                timeout_ms = max(0, min(idle_ms, stats_due_ms))
            else:
                timeout_ms = max(0, min(100, int(tick * 1000)))
            ready = dict(poller.poll(timeout_ms))
            if ctx.control in ready:
                msg = decode(ctx.control.recv())
                if isinstance(msg, Shutdown):
                    break
                actor.on_control(msg, ctx)
            if ctx.inbox in ready:
                msg = decode(ctx.inbox.recv())
                current_index = getattr(msg, "index", current_index)
                t_recv = time.time()
                sent = getattr(msg, "sent_at", 0.0)
                ctx.blocked_s = 0.0
                t0 = time.perf_counter()
                actor.on_message(msg, ctx)
                if actor.measure_messages:
                    service_ms = (time.perf_counter() - t0 - ctx.blocked_s) * 1e3
                    meter.record(service_ms, (t_recv - sent) * 1e3 if sent else None)
            tick = actor.next_tick_s()
            if tick is not None and tick <= 0:
                # Work done on a tick (a source reading a frame, a frame taken from a
                # backlog) is service time; the tick returns the item's sent_at.
                ctx.blocked_s = 0.0
                t_start = time.time()
                t0 = time.perf_counter()
                sent = actor.on_tick(ctx)
                if sent is not None:
                    meter.record((time.perf_counter() - t0 - ctx.blocked_s) * 1e3,
                                 (t_start - sent) * 1e3 if sent else None)
            if time.monotonic() - meter.last >= STATS_PERIOD_S:
                ctx.publish(meter.stats(spec.name, ctx))
            if os.getppid() != parent:  # supervisor vanished: do not linger as an orphan
                break
        actor.teardown(ctx)
        ctx.publish(meter.stats(spec.name, ctx, final=True))
    except CanopyError as exc:
        exit_code = 1
        _report(ctx, spec.name, str(exc), traceback.format_exc(), _failed_index(actor, current_index))
    except Exception as exc:  # an actor must report, never die silently
        exit_code = 1
        _report(ctx, spec.name, f"{type(exc).__name__}: {exc}", traceback.format_exc(),
                _failed_index(actor, current_index))
    finally:
        if ctx is not None:
            ctx.close()
        zctx.term()
    sys.exit(exit_code)


def _failed_index(actor, last_message_index: int) -> int:
    """The frame being worked on: an actor that knows it (the source, reading frame i on a tick)
    says so in ``current_index``; else the index of the last message received."""
    index = getattr(actor, "current_index", None)
    return int(index) if isinstance(index, int) and index >= 0 else last_message_index


def _report(ctx: ActorContext | None, name: str, error: str, detail: str, index: int) -> None:
    if ctx is None:
        sys.stderr.write(f"[{name}] {error}\n")
        return
    try:
        ctx.publish(ActorError(actor=name, error=error, detail=detail, frame_index=index))
    except Exception:
        sys.stderr.write(f"[{name}] {error}\n")
