"""Recorder actor (optional): what the run produces → ``run.mcap`` for Foxglove.

A thin loop around ``canopy.recording.McapRecorder``. It takes, on its inbox:

- ``FrameHandle`` — forwarded by tracking once it has processed the frame; the
  left image (the enhanced one tracking saw) is read from the shared-memory
  ring and written as a PNG. ``image_every`` = N writes every N-th frame
  index (1 = all). A slot overwritten before the recorder got to it counts as
  dropped (``ctx.dropped``), the run goes on.
- ``FramePose`` — written as the camera pose and the ``world → camera`` tf.
  A pose that cannot be written (NaN after a tracking failure) is skipped and
  counted, never fatal: the recorder must not end a run.
- ``MapSnapshot`` — map points and line segments, stamped with the newest
  keyframe's dataset time.
- ``ActorStats`` — if the launcher forwards them: ``/stats/<actor>``.
- ``EndOfStream`` — each upstream sends one after its last message; after
  ``end_of_streams`` of them (one per upstream pipe; PUSH/PULL keeps each pipe
  in order, so nothing is still on the way) the actor stops. If fewer arrive,
  it stops ``eos_grace_s`` after the first one once its inbox has gone quiet.

``teardown`` closes the file, which writes the MCAP summary; that also happens
on a supervisor ``Shutdown`` (an early end) and on SIGTERM (turned into an
orderly stop here). Only SIGKILL skips it: the file then lacks its summary and
the last second or so of data, and is still readable linearly (see
``canopy.recording``).

Config: ``path`` (required), ``ring`` (the enhanced ring; attached at set-up so
a wrong name fails early; handles name their ring anyway), ``image_every``
(default 1), ``right`` (also record the right image, default False),
``image_format`` (``png``/``jpeg``), ``end_of_streams`` (default 1),
``eos_grace_s`` (default 5), ``flush_period_s`` (default 1: an idle recorder
still puts its last writes on disk within that time).
"""
from __future__ import annotations

import signal
import time
from typing import Any

import numpy as np

from actors.runtime import Actor, ActorContext
from canopy.recording import McapRecorder
from protocol.messages import ActorStats, EndOfStream, FrameHandle, FramePose, MapSnapshot
from shared.errors import ConfigError, InputError
from shared.ring import FrameRing, SlotOverwritten

RIGHT_IMAGE_TOPIC = "/camera/right/image"


def stats_values(msg: ActorStats) -> dict:
    """An ``ActorStats`` message as a flat-ish JSON object (latency percentiles, not raw samples)."""
    out: dict[str, Any] = {"pid": msg.pid, "seq": msg.seq, "messages": msg.messages, "dropped": msg.dropped,
                           "cpu_percent": msg.cpu_percent, "rss_mb": msg.rss_mb, "peak_rss_mb": msg.peak_rss_mb,
                           "final": msg.final}
    for name in ("service_ms", "queue_ms"):
        a = np.asarray(getattr(msg, name), np.float64).ravel()
        if a.size:
            out[f"{name}_p50"] = float(np.percentile(a, 50))
            out[f"{name}_p95"] = float(np.percentile(a, 95))
            out[f"{name}_max"] = float(a.max())
            out[f"{name}_n"] = int(a.size)
    if msg.extra:
        out["extra"] = dict(msg.extra)
    return out


class RecorderActor(Actor):
    name = "recorder"

    def __init__(self, config: dict, seed: int = 0):
        super().__init__(config, seed)
        path = config.get("path")
        if not path:
            raise ConfigError("recorder.path", "the recorder needs an output path (.mcap)")
        self.path = str(path)
        try:
            self.image_every = int(config.get("image_every", 1))
            self.end_of_streams = int(config.get("end_of_streams", 1))
            self.eos_grace_s = float(config.get("eos_grace_s", 5.0))
        except (TypeError, ValueError) as exc:
            raise ConfigError("recorder", f"bad number in the recorder config: {exc}") from None
        if self.image_every < 1:
            raise ConfigError("recorder.image_every", f"must be >= 1, got {self.image_every}")
        if self.end_of_streams < 1:
            raise ConfigError("recorder.end_of_streams", f"must be >= 1, got {self.end_of_streams}")
        self.record_right = bool(config.get("right", False))
        self.image_format = str(config.get("image_format", "png"))
        self.flush_period_s = float(config.get("flush_period_s", 1.0))
        self.recorder: McapRecorder | None = None
        self.rings: dict[str, FrameRing] = {}
        self.dropped = 0                       # frames whose slot was overwritten before we read it
        self.counts: dict[str, int] = {}       # what was written / skipped, for ctx.extra
        self.last_stamp: float | None = None   # newest dataset time seen (stamps stats messages)
        self.last_image_index: int | None = None
        self.eos_seen = 0
        self.finished = False
        self._last_message = time.monotonic()

    # -- lifetime (usable without sockets: open / record / close) --------------------------------
    def open(self) -> None:
        self.recorder = McapRecorder(self.path, image_format=self.image_format, flush_period_s=self.flush_period_s)
        if self.config.get("ring"):
            self._ring(self.config["ring"])

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()
        for ring in self.rings.values():
            ring.close()
        self.rings.clear()

    def setup(self, ctx: ActorContext) -> None:
        self.open()
        # The supervisor terminates (SIGTERM) actors that outlive the grace period; stop in order
        # instead, so teardown still writes the MCAP summary.
        signal.signal(signal.SIGTERM, lambda signum, frame: ctx.stop())

    def teardown(self, ctx: ActorContext) -> None:
        self._publish_counts(ctx)
        self.close()

    # -- messages --------------------------------------------------------------------------------
    def _ring(self, name: str) -> FrameRing:
        ring = self.rings.get(name)
        if ring is None:
            ring = self.rings[name] = FrameRing.attach(name)
        return ring

    def _count(self, key: str) -> str:
        self.counts[key] = self.counts.get(key, 0) + 1
        return key

    def _seen(self, stamp: float) -> None:
        stamp = float(stamp)
        if np.isfinite(stamp) and stamp >= 0 and (self.last_stamp is None or stamp > self.last_stamp):
            self.last_stamp = stamp

    def record(self, msg: Any) -> str:
        """Write what ``msg`` carries; return what happened (a key of ``counts``, or ``"dropped"``)."""
        if self.recorder is None:
            raise InputError(self.path, "recorder not opened (call open() or setup() first)")
        self._last_message = time.monotonic()
        if isinstance(msg, FrameHandle):
            return self._frame(msg)
        if isinstance(msg, FramePose):
            try:
                self.recorder.add_pose(msg.timestamp, msg.T_world_cam)
            except InputError:
                return self._count("poses_skipped")
            self._seen(msg.timestamp)
            return self._count("poses")
        if isinstance(msg, MapSnapshot):
            return self._map(msg)
        if isinstance(msg, ActorStats):
            if self.last_stamp is None:  # no dataset time yet: a stamp of 0 would stretch the timeline
                return self._count("stats_skipped")
            self.recorder.add_stats(self.last_stamp, msg.actor, stats_values(msg))
            return self._count("stats")
        if isinstance(msg, EndOfStream):
            self.eos_seen += 1
            if self.eos_seen >= self.end_of_streams:
                self.finished = True
            return self._count("end_of_stream")
        return self._count("ignored")

    def _frame(self, handle: FrameHandle) -> str:
        if self.last_image_index is not None and handle.index - self.last_image_index < self.image_every:
            return self._count("images_skipped")
        try:
            index, stamp, images = self._ring(handle.ring).read(handle.slot, handle.generation)
        except SlotOverwritten:
            self.dropped += 1
            return "dropped"
        self.recorder.add_image(stamp, images[0])
        if self.record_right and len(images) > 1:
            self.recorder.add_image(stamp, images[1], topic=RIGHT_IMAGE_TOPIC, frame_id="camera_right")
        self.last_image_index = index
        self._seen(stamp)
        return self._count("images")

    def _map(self, snap: MapSnapshot) -> str:
        stamps = np.asarray(snap.keyframe_stamps, np.float64).ravel()
        stamps = stamps[np.isfinite(stamps) & (stamps >= 0)]
        stamp = float(stamps.max()) if stamps.size else self.last_stamp
        if stamp is None:
            return self._count("maps_skipped")
        points = np.asarray(snap.points).reshape(-1, 3)
        lines = np.asarray(snap.lines).reshape(-1, 2, 3)
        # An empty layer is written only once something was there (e.g. lines off: no /map/lines).
        if len(points) or self.counts.get("point_maps", 0):
            self.recorder.add_point_cloud(stamp, points)
            self._count("point_maps")
        if len(lines) or self.counts.get("line_maps", 0):
            self.recorder.add_lines(stamp, lines)
            self._count("line_maps")
        return self._count("maps")

    # -- the actor loop --------------------------------------------------------------------------
    def _publish_counts(self, ctx: ActorContext) -> None:
        ctx.dropped = self.dropped
        ctx.extra.update(self.counts)

    def on_message(self, msg: Any, ctx: ActorContext) -> None:
        self.record(msg)
        if self.finished:
            for late in ctx.drain_inbox():  # anything that slipped in beside the last end-of-stream
                self.record(late)
            ctx.stop()
        self._publish_counts(ctx)

    def next_tick_s(self) -> float | None:
        waits = []
        if self.recorder is not None and (flush := self.recorder.seconds_to_flush()) is not None:
            waits.append(flush)  # an idle recorder still puts its last writes on disk within ~1 s
        if self.eos_seen and not self.finished:
            waits.append(self._last_message + self.eos_grace_s - time.monotonic())
        return max(0.0, min(waits)) if waits else None

    def on_tick(self, ctx: ActorContext) -> float | None:
        if self.recorder is not None and (flush := self.recorder.seconds_to_flush()) is not None and flush <= 0:
            self.recorder.flush()
        # Some upstream ended without its end-of-stream reaching us (it was dropped, or it crashed):
        # do not keep the run alive forever waiting for it.
        if self.eos_seen and not self.finished and time.monotonic() - self._last_message >= self.eos_grace_s:
            self.finished = True
            self._count("end_by_timeout")
            ctx.stop()
        return None
