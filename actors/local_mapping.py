"""Local-mapping actor: keyframe in → local BA → local-map update out.

A thin loop around ``canopy.backend.LocalMapper``, which owns the map
(keyframes, landmarks, covisibility). Each update goes back to tracking;
the supervisor gets a snapshot of keyframe poses and map points at most
every ``snapshot_period_s`` and always at the end, so a crash elsewhere
still leaves the map computed so far.
"""
from __future__ import annotations

import time

import numpy as np

from actors.runtime import Actor, ActorContext
from canopy.backend import LocalMapper
from protocol.messages import EndOfStream, KeyframeData, MapSnapshot


class LocalMappingActor(Actor):
    name = "local_mapping"

    def setup(self, ctx: ActorContext) -> None:
        if self.config.get("sensor", "stereo") == "mono":
            from canopy.mono import MonoMapper
            self.mapper = MonoMapper(self.config["calib"], self.config.get("mono"),
                                     pixel_sigma=float(self.config.get("pixel_sigma", 1.0)))
        else:
            self.mapper = LocalMapper(self.config["calib"], self.config["params"])
        self.snapshot_period = float(self.config.get("snapshot_period_s", 0.5))
        self.last_snapshot = 0.0
        self.n_keyframes = 0

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, KeyframeData):
            update = self.mapper.insert_keyframe(msg)
            self.n_keyframes += 1
            # Tracking may already have finished at the end of a realtime run: never block on it.
            ctx.send("tracking", update, block=False)
            ctx.extra.update({"keyframes": self.n_keyframes, "landmarks": len(self.mapper.landmarks),
                              **{f"{k}_ms": float(v) for k, v in update.timings.items()}})
            if time.monotonic() - self.last_snapshot >= self.snapshot_period:
                self._publish_snapshot(ctx, final=False)
        elif isinstance(msg, EndOfStream):
            ctx.stop()

    def _snapshot(self, final: bool) -> MapSnapshot:
        self.last_snapshot = time.monotonic()
        kfs = self.mapper.keyframe_trajectory()
        return MapSnapshot(keyframe_indices=np.asarray(kfs.meta["indices"], np.int64), keyframe_stamps=kfs.stamps,
                           keyframe_poses=kfs.poses,
                           points=np.asarray(self.mapper.map_points(), np.float32).reshape(-1, 3), final=final,
                           lines=np.asarray(self.mapper.map_lines(), np.float32).reshape(-1, 2, 3))

    def _publish_snapshot(self, ctx: ActorContext, final: bool) -> None:
        snap = self._snapshot(final=final)
        ctx.publish(snap)
        if ctx.has_output("recorder"):
            ctx.send("recorder", snap, block=False)

    def teardown(self, ctx: ActorContext) -> None:
        self._publish_snapshot(ctx, final=True)
        if ctx.has_output("recorder"):  # after the final map: the recorder's second end-of-stream
            ctx.send("recorder", EndOfStream(n_frames=self.n_keyframes, sent_at=time.time()), block=False)
