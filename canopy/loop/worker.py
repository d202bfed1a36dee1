"""The loop closer's work at low CPU priority (issue 10: the loop closer never delays tracking).

``LoopWorker`` owns the ``LoopCloser``: keyframe messages handed over with ``submit`` are turned
into place keyframes (bag of words), queried, verified and, on a loop, corrected by the pose
graph, niced to ``niceness`` (19) and by default under SCHED_IDLE (``idle``: a normal task that
wakes preempts it at once, where a nice value alone lets it finish its slice first): it runs on
cycles tracking and local mapping leave (``canopy.loop.priority``). After a loop the full bundle adjustment (AGRI §3.4.2) runs on a
snapshot of the map in a forked child, niced alike (GTSAM holds the GIL for a whole LM step,
seconds on a 400-keyframe map; ORB-SLAM runs its global BA in a thread of the loop closer).
A newer loop stops a running BA and starts another.

By default the work runs in a forked worker *process*, not a thread of the actor: a niced thread
that holds the GIL (a GTSAM call, a numpy or pure-Python stretch) is scheduled so rarely on a
loaded machine that the actor's normal-priority thread waits for the GIL for seconds: at load 30
on 2 cores a nice-19 thread in a GIL-holding C call delayed the other thread by 6.5 s (pure
Python: 2.2 s; the same thread at nice 0: 0.8 s), and the supervisor ended a monocular KITTI run
for a missed 5 s heartbeat of the loop closer. A process shares no GIL. ``process=False`` runs the
same loop in a thread (tests).

Nothing here touches ZeroMQ: what is to be sent comes out of ``outbox`` as
("send", target, message), ("publish", message), ("extra", dict) and ("done", None) / ("error",
text) items, and the actor's main thread (normal priority, which also keeps the heartbeat) sends
them. ``finish()`` at the end of the stream renices the worker and a running BA back to normal
priority (the run is not slowed at its end), lets the worker take the remaining keyframes, waits
for the full BA (the final map carries it) and ends with ("done", None).
"""
from __future__ import annotations

import multiprocessing
import os
import queue
import threading
import time
import traceback

import numpy as np

from canopy.loop.database import FeatureStats
from canopy.loop.full_ba import ba_worker
from canopy.loop.keyframe import PlaceKeyframe, with_bow
from canopy.loop.priority import (exit_with_parent, set_thread_idle, set_thread_niceness, set_tree_niceness, thread_idle,
                                  thread_niceness)
from protocol.messages import LoopKeyframe, LoopResult

BA_POLL_S = 0.2   # how often the worker looks for the full BA's answer while it runs
IDLE_POLL_S = 1.0  # an idle worker process checks this often that the actor is still there
_END, _STOP = "__end_of_stream__", "__stop__"   # strings: they cross a process boundary


def place_keyframe(msg: LoopKeyframe, vocabulary) -> PlaceKeyframe:
    kf = PlaceKeyframe(index=int(msg.index), timestamp=float(msg.timestamp), T_world_cam=np.asarray(msg.T_world_cam, float),
                       uv=np.asarray(msg.uv, np.float64), u_right=np.asarray(msg.u_right, np.float64),
                       depth=np.asarray(msg.depth, np.float64), octave=np.asarray(msg.octave, np.int64),
                       descriptors=np.asarray(msg.descriptors, np.uint8), landmark_ids=np.asarray(msg.landmark_ids, np.int64),
                       stats=FeatureStats.of(np.zeros((0, 2)), msg.line_segments),
                       landmark_positions=np.asarray(msg.landmark_positions, float).reshape(-1, 3))
    return with_bow(kf, vocabulary)


def _lower_priority(niceness: int, idle: bool, tid: int | None = None) -> None:
    """The worker's (or its BA child's) background priority; nothing at niceness 0."""
    if niceness > 0:
        set_thread_niceness(niceness, tid)
        if idle:
            set_thread_idle(True, tid)


def _normal_priority(tid: int | None = None) -> None:
    """Back to SCHED_OTHER at nice 0 (the end of the stream: the run is not slowed at its end)."""
    set_thread_idle(False, tid)   # first: under SCHED_IDLE the nice value means nothing
    set_thread_niceness(0, tid)


def _ba_child(conn, job: dict, niceness: int, idle: bool, parent_pid: int) -> None:
    """The full-BA child process: forked from the worker thread it starts at its priority;
    set again so a fork from another thread gets it too. It dies with its parent."""
    exit_with_parent(parent_pid)
    _lower_priority(niceness, idle)
    ba_worker(conn, job)


class LoopWorker:
    def __init__(self, closer, vocabulary, niceness: int = 19, process: bool = True, idle: bool = True):
        self.closer = closer
        self.vocabulary = vocabulary
        self.niceness = int(niceness)
        self.idle = bool(idle) and self.niceness > 0   # SCHED_IDLE on top of the nice value
        self.process = bool(process)
        ctx = multiprocessing.get_context("fork")
        self.inbox = ctx.Queue() if process else queue.Queue()
        self.outbox = ctx.Queue() if process else queue.Queue()
        self.step_ms: list[float] = []       # the worker's real time per keyframe (BoW, query, verification, PGO)
        self.step_cpu_ms: list[float] = []   # its thread CPU per keyframe (the load-robust figure: it runs niced)
        self.bow_cpu_ms: list[float] = []    # of which the bag of words (vocabulary descent)
        self._ba = None                      # (child process, pipe, epoch of its snapshot, start time)
        self._runner = None                  # the worker thread or process
        self._tid: int | None = None
        self._parent = os.getpid()
        self._started = threading.Event()
        self._finishing = threading.Event()

    # ------------------------------------------------------------------ actor side
    def start(self) -> None:
        if self.process:
            # not a daemon: it forks the full-BA child; it leaves when the actor goes (IDLE_POLL_S)
            self._runner = multiprocessing.get_context("fork").Process(target=self._run, name="canopy-loop-worker")
            self._runner.start()
            self._tid = self._runner.pid
        else:
            self._runner = threading.Thread(target=self._run, name="loop-closer-worker", daemon=True)
            self._runner.start()
            self._started.wait(10.0)

    def submit(self, msg: LoopKeyframe) -> None:
        self.inbox.put(msg)

    def finish(self) -> None:
        """End of the stream: the remaining work at normal priority, then ("done", None)."""
        self._finishing.set()
        self._normal_priority_everywhere()
        self.inbox.put(_END)

    def _normal_priority_everywhere(self) -> None:
        """The worker (and a running full BA) back to SCHED_OTHER at nice 0, from the actor's side:
        at the end of the stream, and at teardown, where the worker must get a core to leave."""
        if self.niceness > 0 and self._tid is not None:
            if self.process:  # every thread of the worker process and its full-BA child
                set_tree_niceness(self._tid, 0, idle=False)
            else:
                _normal_priority(self._tid)
                ba = self._ba
                if ba is not None:
                    _normal_priority(ba[0].pid)

    def stop(self) -> None:
        """Teardown: the worker leaves after its current step, a running BA is stopped."""
        if self._runner is None:
            return
        self._normal_priority_everywhere()  # a SCHED_IDLE worker on busy cores would not get to _STOP
        try:
            self.inbox.put(_STOP)
        except (OSError, ValueError):
            pass
        self._runner.join(30.0)
        if self.process and self._runner.is_alive():
            self._runner.terminate()
            self._runner.join(5.0)
        if not self.process and self._ba is not None:
            self._stop_ba()

    def outbox_fd(self) -> int | None:
        """The file descriptor that turns readable when the worker process puts an answer in
        ``outbox`` (a multiprocessing queue is a pipe), so the actor can block on it instead of
        polling; None for a thread worker (a ``queue.Queue`` has none)."""
        return self.outbox._reader.fileno() if self.process else None

    def alive(self) -> bool:
        return self._runner is not None and self._runner.is_alive()

    @property
    def thread_id(self) -> int | None:
        """Native id of the worker thread, or pid of the worker process."""
        return self._tid

    def step_stats(self) -> dict:
        if not self.step_ms:
            return {}
        a = np.asarray(self.step_ms[-2000:], float)
        out = {"step_ms_p50": float(np.percentile(a, 50)), "step_ms_p95": float(np.percentile(a, 95)),
               "step_ms_max": float(a.max()), "steps": len(self.step_ms)}
        if self.step_cpu_ms:
            c, b = np.asarray(self.step_cpu_ms, float), np.asarray(self.bow_cpu_ms, float)
            out.update({"step_cpu_ms_p50": float(np.percentile(c, 50)), "step_cpu_ms_mean": float(c.mean()),
                        "step_cpu_s": float(c.sum() / 1e3), "bow_cpu_ms_p50": float(np.percentile(b, 50))})
        return out

    # ------------------------------------------------------------------ worker thread / process
    def _run(self) -> None:
        if self.process:  # a SIGKILLed actor takes its worker along (see exit_with_parent)
            exit_with_parent(self._parent)
        self._tid = threading.get_native_id()
        if not self._finishing.is_set():   # a process: its only thread; the queue's feeder inherits it
            _lower_priority(self.niceness, self.idle)
        self.outbox.put(("extra", {"worker_niceness": thread_niceness(), "worker_idle": bool(thread_idle()),
                                   "worker_process": self.process}))
        self._started.set()
        try:
            while True:
                if self._ba is not None:
                    timeout = BA_POLL_S
                elif self.closer.ba_pending:
                    timeout = 0.0
                else:
                    timeout = IDLE_POLL_S if self.process else None
                try:
                    item = self.inbox.get(timeout=timeout) if timeout != 0.0 else self.inbox.get_nowait()
                except queue.Empty:
                    item = None
                    if self.process and os.getppid() != self._parent:  # the actor is gone
                        item = _STOP
                if isinstance(item, str) and item == _STOP:
                    if self._ba is not None:
                        self._stop_ba()
                    return
                if isinstance(item, str) and item == _END:
                    # normal priority from here (finish() reniced this worker already where it could;
                    # a BA started since then was forked niced)
                    self._finishing.set()
                    if self.niceness > 0:
                        _normal_priority()
                        if self._ba is not None:
                            _normal_priority(self._ba[0].pid)
                    self._finish_ba()
                    self.outbox.put(("extra", {**self.step_stats(), "worker_niceness_at_end": thread_niceness(),
                                               "worker_idle_at_end": bool(thread_idle())}))
                    self.outbox.put(("done", None))
                    return
                if item is not None:
                    self.step(item)
                if self._ba is not None:
                    self._poll_ba(0.0)
                elif self.closer.ba_pending and self.inbox.empty():
                    self._start_ba()
        except Exception as exc:  # the actor's main thread reports it (an actor never dies silently)
            self.outbox.put(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
        finally:
            if self.process:  # everything put is delivered before the process ends
                self.outbox.close()
                self.outbox.join_thread()

    def step(self, msg: LoopKeyframe) -> None:
        """One keyframe: bag of words, detection, verification and, on a loop, the pose graph."""
        t0, c0 = time.perf_counter(), time.thread_time()
        kf = place_keyframe(msg, self.vocabulary)
        t_bow = (time.perf_counter() - t0) * 1e3
        self.bow_cpu_ms.append((time.thread_time() - c0) * 1e3)
        closure = self.closer.add_keyframe(kf, {int(k): v for k, v in msg.window_poses.items()},
                                           epoch=int(msg.loop_epoch))
        if closure is not None and self._ba is not None:
            self._stop_ba()  # its snapshot predates this loop; a new one is pending
        if closure is None:
            self.outbox.put(("send", "local_mapping", LoopResult(keyframe_index=kf.index, loops=self.closer.n_loops,
                                                                 timings_ms={"bow": t_bow}, sent_at=time.time())))
        else:
            ids = np.array(sorted(closure.corrections), np.int64)
            result = LoopResult(keyframe_index=kf.index, closed=True, candidate=closure.constraint.candidate,
                                n_inliers=closure.constraint.n_inliers, keyframe_ids=ids,
                                corrections=np.array([closure.corrections[k] for k in ids.tolist()]).reshape(-1, 4, 4),
                                loops=self.closer.n_loops, timings_ms={"bow": t_bow, **closure.timings_ms},
                                sent_at=time.time(), fused=np.array(sorted(closure.fused.items()), np.int64).reshape(-1, 2))
            self.outbox.put(("send", "local_mapping", result))
            self.outbox.put(("publish", LoopResult(keyframe_index=kf.index, closed=True, candidate=result.candidate,
                                                   n_inliers=result.n_inliers, loops=result.loops,
                                                   timings_ms=result.timings_ms, sent_at=result.sent_at)))
        self.step_ms.append((time.perf_counter() - t0) * 1e3)
        self.step_cpu_ms.append((time.thread_time() - c0) * 1e3)
        s = self.closer.detector.stats
        self.outbox.put(("extra", {"loops": self.closer.n_loops, "fused": len(self.closer.alias), "keyframes": s.keyframes,
                                   "queries": s.queries, "candidates": s.candidates, "consistent": s.consistent,
                                   "verified": s.verified, **{f"rejected_{k}": v for k, v in s.rejected.items()},
                                   **self.step_stats()}))

    # ------------------------------------------------------------------ full BA in a child process
    def _start_ba(self) -> None:
        """Run the full BA on a snapshot in a forked child process, so the worker keeps taking
        keyframes (one LM step on a 400-keyframe map takes seconds)."""
        job = self.closer.ba_job()
        if job is None:
            return
        mp = multiprocessing.get_context("fork")
        parent, child = mp.Pipe(duplex=False)
        niceness = 0 if self._finishing.is_set() else self.niceness
        proc = mp.Process(target=_ba_child, args=(child, job, niceness, self.idle, os.getpid()), daemon=True,
                          name="canopy-full-ba")
        proc.start()
        child.close()
        self._ba = (proc, parent, job["epoch"], time.perf_counter())
        if niceness > 0 and self._finishing.is_set():  # finish() came meanwhile
            _normal_priority(proc.pid)

    def _stop_ba(self) -> None:
        """A newer loop makes the running BA's snapshot stale (ORB-SLAM aborts its global BA too)."""
        proc, conn, _, _ = self._ba
        proc.terminate()
        proc.join(5.0)
        conn.close()
        self._ba = None

    def _poll_ba(self, wait_s: float) -> None:
        proc, conn, epoch, t0 = self._ba
        if not conn.poll(wait_s):
            if not proc.is_alive() and not conn.poll(0):
                self._ba = None
                self.outbox.put(("extra", {"global_ba_error": f"full BA process ended with code {proc.exitcode}"}))
            return
        try:
            status, payload = conn.recv()
        except EOFError:
            status, payload = "error", f"full BA process ended with code {proc.exitcode}"
        proc.join(5.0)
        conn.close()
        self._ba = None
        if status != "ok":
            self.outbox.put(("extra", {"global_ba_error": payload}))
            return
        if epoch != self.closer.epoch:  # a correction came in meanwhile: redo it on the new map
            self.closer.ba_pending = True
            return
        self._send_ba(self.closer.accept_ba(payload), (time.perf_counter() - t0) * 1e3)

    def _finish_ba(self) -> None:
        """At the end of the stream: wait for the running BA (starting the pending one)."""
        for _ in range(3):  # a BA made stale by a last loop is run once more
            if self._ba is None and self.closer.ba_pending:
                self._start_ba()
            while self._ba is not None:
                self._poll_ba(1.0)
            if not self.closer.ba_pending:
                return

    def _send_ba(self, result, wall_ms: float) -> None:
        ids = np.array(sorted(result.corrections), np.int64)
        self.outbox.put(("send", "local_mapping", LoopResult(
            keyframe_index=max(self.closer.poses), global_ba=True, keyframe_ids=ids,
            corrections=np.array([result.corrections[k] for k in ids.tolist()]).reshape(-1, 4, 4),
            landmark_ids=result.landmark_ids, landmark_positions=result.positions, loops=self.closer.n_loops,
            timings_ms={f"global_ba_{k}": v for k, v in result.timings_ms.items()}, sent_at=time.time())))
        self.outbox.put(("extra", {"global_ba": len(self.closer.ba_results), "global_ba_ms": result.timings_ms["total"],
                                   "global_ba_wall_ms": wall_ms, "global_ba_edges": result.n_edges,
                                   "global_ba_outliers": result.n_outliers,
                                   "global_ba_pixel_sigma": getattr(result, "pixel_sigma", None)}))
