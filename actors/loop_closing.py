"""Loop-closing actor: keyframe from local mapping → detection, verification, pose graph →
correction back to local mapping (which forwards the corrected map to tracking).

A thin loop around ``canopy.loop.LoopCloser``. Every keyframe is answered with a
``LoopResult`` (closed or not), so that local mapping can, in lockstep, wait for the
answer and keep runs repeatable; closed loops also go to the supervisor, which counts
them in the outputs. Tracking never waits on this actor.

After a loop, the full bundle adjustment (AGRI §3.4.2) runs here on a tick, once the
keyframes that arrived meanwhile have been taken in (ORB-SLAM runs its global BA in a thread
of the loop closer); its answer goes to local mapping as a ``LoopResult`` with
``global_ba`` set, applied like a pose-graph correction. At the end of the stream a pending
BA runs before the end is passed on, so the final map carries it.
"""
from __future__ import annotations

import time

import numpy as np

from actors.runtime import Actor, ActorContext
from canopy.loop.closer import LoopCloser
from canopy.loop.keyframe import PlaceKeyframe, with_bow
from canopy.loop.database import FeatureStats
from canopy.loop.vocabulary import load_vocabulary
from protocol.messages import EndOfStream, LoopKeyframe, LoopResult


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
        self.vocabulary = load_vocabulary(params.vocabulary)
        self.closer = LoopCloser(self.config["calib"], params, self.vocabulary)
        ctx.extra.update({"loops": 0, "vocabulary": getattr(self.vocabulary, "name", "")})

    def on_message(self, msg, ctx: ActorContext) -> None:
        if isinstance(msg, LoopKeyframe):
            t0 = time.perf_counter()
            kf = place_keyframe(msg, self.vocabulary)
            t_bow = (time.perf_counter() - t0) * 1e3
            closure = self.closer.add_keyframe(kf, {int(k): v for k, v in msg.window_poses.items()},
                                               epoch=int(msg.loop_epoch))
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
            if self.closer.ba_pending:
                self._global_ba(ctx)
            ctx.send("local_mapping", EndOfStream(n_frames=msg.n_frames, sent_at=time.time()), block=False)
            ctx.stop()

    def next_tick_s(self) -> float | None:
        return 0.0 if self.closer.ba_pending else None

    def on_tick(self, ctx: ActorContext) -> float | None:
        for msg in ctx.drain_inbox():  # keyframes that arrived first join the BA
            self.on_message(msg, ctx)
            if ctx.stop_requested:
                return None
        if self.closer.ba_pending:
            self._global_ba(ctx)
        return None

    def _global_ba(self, ctx: ActorContext) -> None:
        def step() -> None:  # keeps the supervisor and local mapping's end-of-run wait informed
            ctx.heartbeat()
            ctx.send("local_mapping", LoopResult(keyframe_index=-1, loops=self.closer.n_loops, sent_at=time.time()),
                     block=False)

        result = self.closer.global_bundle_adjust(on_iteration=step)
        if result is None:
            return
        ids = np.array(sorted(result.corrections), np.int64)
        ctx.send("local_mapping", LoopResult(
            keyframe_index=max(self.closer.poses), global_ba=True, keyframe_ids=ids,
            corrections=np.array([result.corrections[k] for k in ids.tolist()]).reshape(-1, 4, 4),
            landmark_ids=result.landmark_ids, landmark_positions=result.positions, loops=self.closer.n_loops,
            timings_ms={f"global_ba_{k}": v for k, v in result.timings_ms.items()}, sent_at=time.time()))
        ctx.extra.update({"global_ba": len(self.closer.ba_results), "global_ba_ms": result.timings_ms["total"],
                          "global_ba_edges": result.n_edges, "global_ba_outliers": result.n_outliers})
