"""Local-mapping actor: keyframe in → local BA → local-map update out.

A thin loop around ``canopy.backend.LocalMapper``, which owns the map
(keyframes, landmarks, covisibility). Each update goes back to tracking;
the supervisor gets a snapshot of keyframe poses and map points at most
every ``snapshot_period_s`` and always at the end, so a crash elsewhere
still leaves the map computed so far. The rate cap never withholds the last
change: a map changed since the last snapshot (a keyframe, a loop correction)
is published once the period has passed even if nothing else arrives, and
before a remote ``save_map`` is written, so a client that paused the run is
shown (``map`` request, map deltas) exactly the map it then saves.

With loop closing on, each inserted keyframe also goes to the loop closer;
its answers are applied whenever they arrive (never waited for, so the loop
closer adds nothing to tracking's wait for map updates) and the corrected
local map goes to tracking then. Each correction is an epoch: a keyframe
tracking computed before a correction reached it carries the older epoch
and is brought up to date on insertion. Runs without a loop stay
repeatable in lockstep; when a loop closes, the keyframe at which its
correction lands may vary by one or two between runs. At the end the loop
closer is drained before the final map is published.
"""
from __future__ import annotations

import threading
import time

import numpy as np

from actors.runtime import Actor, ActorContext
from actors.schedstat import thread_report, thread_schedstat
from canopy.backend import LocalMapper
from canopy.backend.final_ba import finish_map
from canopy.loop.correction import corrections_from_arrays
from canopy.loop.mapping_hooks import apply_loop_result, catch_up_pose, loop_keyframe_message, remap_landmarks
from protocol.messages import EndOfStream, KeyframeData, LoopResult, MapSaved, MapSnapshot, SaveMapRequest


class LocalMappingActor(Actor):
    name = "local_mapping"

    def setup(self, ctx: ActorContext) -> None:
        self.mono = self.config.get("sensor", "stereo") == "mono"
        if self.mono:
            from canopy.mono import MonoMapper
            self.mapper = MonoMapper(self.config["calib"], self.config.get("mono"),
                                     pixel_sigma=float(self.config.get("pixel_sigma", 1.0)))
        else:
            self.mapper = LocalMapper(self.config["calib"], self.config["params"])
            if self.config.get("load_map"):  # --load-map: the saved map is the map this run starts from
                from canopy.loop.map_io import load_map, restore_mapper
                restore_mapper(load_map(self.config["load_map"], self.config["calib"]), self.mapper)
        self.snapshot_period = float(self.config.get("snapshot_period_s", 0.5))
        self.last_snapshot = 0.0
        self.map_changed = False  # since the last snapshot published (next_tick_s publishes it late)
        self.n_keyframes = 0
        self.loop_on = ctx.has_output("loop_closing")
        self.loop_wait_s = float(self.config.get("lockstep_wait_s", 60.0))
        self.last_update = None
        self.loops = 0
        self.loop_epoch = 0                      # loop corrections applied to the map
        self.epoch_corrections: dict[int, dict] = {}  # epoch -> keyframe corrections of that loop
        self.landmark_alias: dict[int, int] = {}  # landmarks fused across a loop -> the one kept
        # the threads' scheduler statistics from the first keyframe on (stats.json "threads": local
        # mapping's CPU per tracked frame is what it takes from tracking's two cores)
        self.sched_start = None
        self.n_frames = 0

    def on_control(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, SaveMapRequest):  # a remote client's save_map (actors.inspection)
            from canopy.loop.map_io import map_from_mapper, save_map
            if self.map_changed:  # the stream shows the map about to be saved, and only that map
                self._publish_snapshot(ctx, final=False)
            try:
                save_map(msg.path, map_from_mapper(self.mapper, self.config.get("vocabulary_id", "")))
                saved = MapSaved(path=msg.path, ok=True, keyframes=len(self.mapper.keyframes),
                                 points=len(self.mapper.landmarks))
            except Exception as exc:  # a failed save is reported to the client, never ends the run
                saved = MapSaved(path=msg.path, ok=False, error=f"{type(exc).__name__}: {exc}")
            ctx.publish(saved)

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, KeyframeData):
            if self.sched_start is None:
                self.sched_start = thread_schedstat()
            if msg.loop_epoch < self.loop_epoch:  # tracked before the latest correction reached tracking
                msg.T_world_cam = catch_up_pose(msg.index, msg.T_world_cam, self.epoch_corrections,
                                                msg.loop_epoch, self.loop_epoch)
                if self.mono:  # the corrections are similarities: keep the pose rigid
                    from canopy.loop.sim3 import rigid_pose
                    msg.T_world_cam = rigid_pose(msg.T_world_cam)
            remap_landmarks(msg, self.landmark_alias)
            update = self.mapper.insert_keyframe(msg)
            self.map_changed = True
            self.n_keyframes += 1
            self.last_update = update
            update.loop_epoch = self.loop_epoch
            # Tracking may already have finished at the end of a realtime run: never block on it.
            # Tracking first: it waits for this update (lockstep), the loop closer does not, so
            # building and encoding the loop keyframe stays off tracking's path.
            ctx.send("tracking", update, block=False)
            if self.loop_on:
                if self.mono:
                    from canopy.loop.mono import mono_loop_keyframe_message
                    loop_msg = mono_loop_keyframe_message(msg, self.mapper, update)
                else:
                    loop_msg = loop_keyframe_message(msg, self.mapper, update)
                loop_msg.loop_epoch = self.loop_epoch  # the loop closer brings older poses up to date
                ctx.send("loop_closing", loop_msg)
            ctx.extra.update({"keyframes": self.n_keyframes, "landmarks": len(self.mapper.landmarks),
                              **{f"{k}_ms": float(v) for k, v in update.timings.items()}})
            if time.monotonic() - self.last_snapshot >= self.snapshot_period:
                self._publish_snapshot(ctx, final=False)
        elif isinstance(msg, LoopResult):  # a correction arriving between keyframes
            if self._on_loop_result(msg, self.last_update) and self.last_update is not None:
                self.last_update.loop_epoch = self.loop_epoch
                ctx.send("tracking", self.last_update, block=False)
        elif isinstance(msg, EndOfStream):
            self.n_frames = int(msg.n_frames)
            if self.loop_on:
                self._drain_loop_closer(msg, ctx)
            if not self.mono:   # mapping.final_ba, before teardown's final snapshot
                done = finish_map(self.mapper)
                if done is not None:
                    ctx.extra["final_ba"] = done
                    self.map_changed = True
            ctx.stop()

    def _on_loop_result(self, result: LoopResult, update) -> bool:
        if self.mono:
            from canopy.loop.mono import apply_mono_loop_result
            changed = apply_mono_loop_result(self.mapper, result, update)
        else:
            changed = apply_loop_result(self.mapper, result, update, self.landmark_alias)
            if changed and result.closed and int(result.candidate) >= 0:  # the loop's keyframes stay (culling)
                self.mapper.keep_loop_edge(result.keyframe_index, result.candidate)
        self.loops = max(self.loops, int(result.loops))
        if changed:
            self.map_changed = True
            self.loop_epoch += 1
            self.epoch_corrections[self.loop_epoch] = corrections_from_arrays(result.keyframe_ids, result.corrections)
        return changed

    def _drain_loop_closer(self, end: EndOfStream, ctx: ActorContext) -> None:
        """Forward the end of stream and apply the loop closer's remaining answers until it
        ends too, so that the final map carries every correction."""
        ctx.send("loop_closing", EndOfStream(n_frames=end.n_frames, sent_at=time.time()), block=False)
        deadline = time.monotonic() + self.loop_wait_s
        while time.monotonic() < deadline:
            msg = ctx.recv_inbox(100)
            if isinstance(msg, LoopResult):
                self._on_loop_result(msg, None)
                deadline = time.monotonic() + self.loop_wait_s  # alive (a full BA reports each step)
            elif isinstance(msg, EndOfStream):
                return

    def next_tick_s(self) -> float | None:
        """A changed map not yet published: when its snapshot is due (the rate cap's trailing edge).
        Without it the last keyframes before a pause (or the run's idle end) stayed unpublished
        until the next keyframe: a paused client's ``map`` request and its map deltas showed an
        older map than the one ``save_map`` wrote (a keyframe every 3 frames on EuRoC lands a
        second keyframe within the period)."""
        if not self.map_changed:
            return None
        return self.last_snapshot + self.snapshot_period - time.monotonic()

    def on_tick(self, ctx: ActorContext) -> float | None:
        self._publish_snapshot(ctx, final=False)
        return None  # not a message: local mapping's service times stay per keyframe

    def _snapshot(self, final: bool) -> MapSnapshot:
        self.last_snapshot = time.monotonic()
        self.map_changed = False
        kfs = self.mapper.keyframe_trajectory()
        return MapSnapshot(keyframe_indices=np.asarray(kfs.meta["indices"], np.int64), keyframe_stamps=kfs.stamps,
                           keyframe_poses=kfs.poses,
                           points=np.asarray(self.mapper.map_points(), np.float32).reshape(-1, 3), final=final,
                           lines=np.asarray(self.mapper.map_lines(), np.float32).reshape(-1, 2, 3),
                           # same order as map_points (dict order): inspection clients get map deltas
                           point_ids=np.fromiter(self.mapper.landmarks.keys(), np.int64, len(self.mapper.landmarks)))

    def _publish_snapshot(self, ctx: ActorContext, final: bool) -> None:
        snap = self._snapshot(final=final)
        ctx.publish(snap)
        if ctx.has_output("recorder"):
            ctx.send("recorder", snap, block=False)

    def teardown(self, ctx: ActorContext) -> None:
        if self.sched_start is not None:  # per frame of the stream (per keyframe if it never ended)
            ctx.extra["threads"] = thread_report(self.sched_start, thread_schedstat(),
                                                 {threading.get_native_id(): "local_mapping"},
                                                 self.n_frames or self.n_keyframes)
        self._publish_snapshot(ctx, final=True)
        if self.config.get("save_map"):  # --save-map: the final (loop-corrected) map, versioned msgpack
            from canopy.loop.map_io import map_from_mapper, save_map
            save_map(self.config["save_map"], map_from_mapper(self.mapper, self.config.get("vocabulary_id", "")))
        if ctx.has_output("recorder"):  # after the final map: the recorder's second end-of-stream
            ctx.send("recorder", EndOfStream(n_frames=self.n_keyframes, sent_at=time.time()), block=False)
