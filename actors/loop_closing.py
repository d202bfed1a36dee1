"""Loop-closing actor: keyframe from local mapping → detection, verification, pose graph →
correction back to local mapping (which forwards the corrected map to tracking).

A thin loop around ``canopy.loop.LoopCloser``. Every keyframe is answered with a
``LoopResult`` (closed or not), so that local mapping can, in lockstep, wait for the
answer and keep runs repeatable; closed loops also go to the supervisor, which counts
them in the outputs. Tracking never waits on this actor.

After a loop, the full bundle adjustment (AGRI §3.4.2) runs on a snapshot of the map in a
forked child process (ORB-SLAM runs its global BA in a thread of the loop closer; GTSAM holds
the GIL for a whole LM step, so here it is a process), while this actor goes on taking
keyframes; its answer goes to local mapping as a ``LoopResult`` with ``global_ba`` set,
applied like a pose-graph correction. A newer loop stops a running BA and starts a new one.
At the end of the stream the BA is waited for before the end is passed on, so the final map
carries it.
"""
from __future__ import annotations

import multiprocessing
import os
import time

import numpy as np

from actors.runtime import Actor, ActorContext
from canopy.loop.closer import LoopCloser
from canopy.loop.full_ba import ba_worker
from canopy.loop.keyframe import PlaceKeyframe, with_bow
from canopy.loop.database import FeatureStats
from canopy.loop.vocabulary import load_vocabulary
from protocol.messages import EndOfStream, LoopKeyframe, LoopResult

BA_POLL_S = 0.2  # how often the actor looks for the full BA's answer while it runs


def place_keyframe(msg: LoopKeyframe, vocabulary) -> PlaceKeyframe:
    kf = PlaceKeyframe(index=int(msg.index), timestamp=float(msg.timestamp), T_world_cam=np.asarray(msg.T_world_cam, float),
                       uv=np.asarray(msg.uv, np.float64), u_right=np.asarray(msg.u_right, np.float64),
                       depth=np.asarray(msg.depth, np.float64), octave=np.asarray(msg.octave, np.int64),
                       descriptors=np.asarray(msg.descriptors, np.uint8), landmark_ids=np.asarray(msg.landmark_ids, np.int64),
                       stats=FeatureStats.of(np.zeros((0, 2)), msg.line_segments),
                       landmark_positions=np.asarray(msg.landmark_positions, float).reshape(-1, 3))
    return with_bow(kf, vocabulary)


class LoopClosingActor(Actor):
    name = "loop_closing"

    def setup(self, ctx: ActorContext) -> None:
        params = self.config["params"]
        if getattr(params, "niceness", 0) > 0:  # yield the cores to tracking and local mapping (LoopParams.niceness)
            os.nice(int(params.niceness))
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
        self._ba = None  # (child process, pipe, epoch of its snapshot, start time) of a running full BA
        ctx.extra.update({"loops": 0, "vocabulary": getattr(self.vocabulary, "name", "")})

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, LoopKeyframe):
            t0 = time.perf_counter()
            kf = place_keyframe(msg, self.vocabulary)
            t_bow = (time.perf_counter() - t0) * 1e3
            closure = self.closer.add_keyframe(kf, {int(k): v for k, v in msg.window_poses.items()},
                                               epoch=int(msg.loop_epoch))
            if closure is not None and self._ba is not None:
                self._stop_ba()  # its snapshot predates this loop; a new one is pending
            if closure is None:
                ctx.send("local_mapping", LoopResult(keyframe_index=kf.index, loops=self.closer.n_loops,
                                                     timings_ms={"bow": t_bow}, sent_at=time.time()))
            else:
                ids = np.array(sorted(closure.corrections), np.int64)
                result = LoopResult(keyframe_index=kf.index, closed=True, candidate=closure.constraint.candidate,
                                    n_inliers=closure.constraint.n_inliers, keyframe_ids=ids,
                                    corrections=np.array([closure.corrections[k] for k in ids.tolist()]).reshape(-1, 4, 4),
                                    loops=self.closer.n_loops, timings_ms={"bow": t_bow, **closure.timings_ms},
                                    sent_at=time.time(),
                                    fused=np.array(sorted(closure.fused.items()), np.int64).reshape(-1, 2))
                ctx.send("local_mapping", result)
                ctx.publish(LoopResult(keyframe_index=kf.index, closed=True, candidate=result.candidate,
                                       n_inliers=result.n_inliers, loops=result.loops, timings_ms=result.timings_ms,
                                       sent_at=result.sent_at))
            s = self.closer.detector.stats
            ctx.extra.update({"loops": self.closer.n_loops, "fused": len(self.closer.alias), "keyframes": s.keyframes, "queries": s.queries,
                              "candidates": s.candidates, "consistent": s.consistent, "verified": s.verified,
                              **{f"rejected_{k}": v for k, v in s.rejected.items()}})
        elif isinstance(msg, EndOfStream):
            self._finish_ba(ctx)  # the final map carries the full BA
            ctx.send("local_mapping", EndOfStream(n_frames=msg.n_frames, sent_at=time.time()), block=False)
            ctx.stop()

    # ------------------------------------------------------------------ full BA in a child process
    def next_tick_s(self) -> float | None:
        if self._ba is not None:
            return BA_POLL_S
        return 0.0 if self.closer.ba_pending else None

    def on_tick(self, ctx: ActorContext) -> float | None:
        if self._ba is not None:
            self._poll_ba(ctx, wait_s=0.0)
        elif self.closer.ba_pending:
            self._start_ba()
        return None

    def _start_ba(self) -> None:
        """Run the full BA on a snapshot in a forked child process, so this actor keeps taking
        keyframes and reporting (one LM step on a 400-keyframe map takes seconds)."""
        job = self.closer.ba_job()
        if job is None:
            return
        mp = multiprocessing.get_context("fork")
        parent, child = mp.Pipe(duplex=False)
        proc = mp.Process(target=ba_worker, args=(child, job), daemon=True, name="canopy-full-ba")
        proc.start()
        child.close()
        self._ba = (proc, parent, job["epoch"], time.perf_counter())

    def _stop_ba(self) -> None:
        """A newer loop makes the running BA's snapshot stale (ORB-SLAM aborts its global BA too)."""
        proc, conn, _, _ = self._ba
        proc.terminate()
        proc.join(5.0)
        conn.close()
        self._ba = None

    def _poll_ba(self, ctx: ActorContext, wait_s: float) -> None:
        proc, conn, epoch, t0 = self._ba
        if not conn.poll(wait_s):
            if not proc.is_alive() and not conn.poll(0):
                self._ba = None
                ctx.extra["global_ba_error"] = f"full BA process ended with code {proc.exitcode}"
            return
        try:
            status, payload = conn.recv()
        except EOFError:
            status, payload = "error", f"full BA process ended with code {proc.exitcode}"
        proc.join(5.0)
        conn.close()
        self._ba = None
        if status != "ok":
            ctx.extra["global_ba_error"] = payload
            return
        if epoch != self.closer.epoch:  # a correction came in meanwhile: redo it on the new map
            self.closer.ba_pending = True
            return
        self._send_ba(ctx, self.closer.accept_ba(payload), (time.perf_counter() - t0) * 1e3)

    def _finish_ba(self, ctx: ActorContext) -> None:
        """At the end of the stream: wait for the running BA (starting the pending one),
        telling local mapping at each poll that the loop closer is still at work."""
        for _ in range(3):  # a BA made stale by a last loop is run once more
            if self._ba is None and self.closer.ba_pending:
                self._start_ba()
            while self._ba is not None:
                ctx.heartbeat()
                ctx.send("local_mapping", LoopResult(keyframe_index=-1, loops=self.closer.n_loops,
                                                     sent_at=time.time()), block=False)
                self._poll_ba(ctx, wait_s=1.0)
            if not self.closer.ba_pending:
                return

    def _send_ba(self, ctx: ActorContext, result, wall_ms: float) -> None:
        ids = np.array(sorted(result.corrections), np.int64)
        ctx.send("local_mapping", LoopResult(
            keyframe_index=max(self.closer.poses), global_ba=True, keyframe_ids=ids,
            corrections=np.array([result.corrections[k] for k in ids.tolist()]).reshape(-1, 4, 4),
            landmark_ids=result.landmark_ids, landmark_positions=result.positions, loops=self.closer.n_loops,
            timings_ms={f"global_ba_{k}": v for k, v in result.timings_ms.items()}, sent_at=time.time()))
        ctx.extra.update({"global_ba": len(self.closer.ba_results), "global_ba_ms": result.timings_ms["total"],
                          "global_ba_wall_ms": wall_ms, "global_ba_edges": result.n_edges,
                          "global_ba_outliers": result.n_outliers})

    def teardown(self, ctx: ActorContext) -> None:
        if self._ba is not None:
            self._stop_ba()
