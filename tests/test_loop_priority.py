"""The loop closer's niceness helpers and its worker thread (canopy.loop.priority, canopy.loop.worker):
one thread reniced, the rest of the process (the actor's messages and heartbeat) left alone."""
from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from canopy.loop.priority import PER_THREAD, set_process_niceness, set_thread_niceness, thread_idle, thread_niceness
from shared.errors import ConfigError

IDLE_POLICY = hasattr(os, "SCHED_IDLE")

pytestmark = pytest.mark.skipif(not PER_THREAD, reason="nice values are per thread only on Linux")


def test_renicing_one_thread_leaves_the_calling_thread_alone():
    main = thread_niceness()
    seen = {}

    def work():
        seen["ok"] = set_thread_niceness(19)
        seen["mine"] = thread_niceness()
        seen["tid"] = threading.get_native_id()

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert seen["ok"] and seen["mine"] == 19
    assert thread_niceness() == main            # the caller's thread is untouched
    assert os.getpriority(os.PRIO_PROCESS, os.getpid()) == main


def test_another_thread_is_reniced_by_its_id_and_back_when_allowed():
    ready, release = threading.Event(), threading.Event()
    box = {}

    def work():
        box["tid"] = threading.get_native_id()
        set_thread_niceness(19)
        ready.set()
        release.wait(10)

    t = threading.Thread(target=work)
    t.start()
    ready.wait(10)
    try:
        assert thread_niceness(box["tid"]) == 19
        back = set_thread_niceness(0, box["tid"])   # raising priority needs CAP_SYS_NICE / RLIMIT_NICE
        assert thread_niceness(box["tid"]) == (0 if back else 19)
    finally:
        release.set()
        t.join()


def test_a_process_forked_from_a_niced_thread_starts_niced():
    box = _fork_from_a_lowered_thread(lambda: set_thread_niceness(19), thread_niceness)
    assert box["child"] == 19
    assert not set_process_niceness(2**22 + 12345, 5)        # no such process: False, no exception


def _fork_from_a_lowered_thread(lower, probe) -> dict:
    """In a new thread: ``lower()`` its priority, ``probe()`` it, fork a process that sends back its
    own ``probe()``. Returns {"set": lower's result, "mine": the thread's probe, "child": the child's}."""
    import multiprocessing

    mp = multiprocessing.get_context("fork")
    box = {}

    def work():
        box["set"] = lower()
        box["mine"] = probe()
        parent, child = mp.Pipe(duplex=False)
        p = mp.Process(target=_report, args=(child, probe))
        p.start()
        box["child"] = parent.recv()
        p.join(10)

    t = threading.Thread(target=work)
    t.start()
    t.join(30)
    return box


def _report(conn, probe):
    conn.send(probe())


def test_bad_niceness_is_named():
    with pytest.raises(ConfigError, match="niceness"):
        set_thread_niceness(25)


@pytest.mark.parametrize("process", [True, False])
def test_loop_worker_runs_niced_and_finishes_at_normal_priority(process):
    from canopy.loop.closer import LoopCloser
    from canopy.loop.params import LoopParams
    from canopy.loop.worker import LoopWorker
    from shared.types import StereoCalibration

    calib = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)
    main = thread_niceness()
    worker = LoopWorker(LoopCloser(calib, LoopParams(), None), None, niceness=19, process=process)
    worker.start()
    try:
        first = worker.outbox.get(timeout=30)   # the worker has started (and reniced itself)
        assert first == ("extra", {"worker_niceness": 19, "worker_idle": IDLE_POLICY, "worker_process": process})
        assert thread_niceness(worker.thread_id) == 19 and thread_niceness() == main
        assert thread_idle(worker.thread_id) == IDLE_POLICY and not thread_idle()
        worker.finish()
        items = [worker.outbox.get(timeout=10)]
        while items[-1][0] != "done":
            items.append(worker.outbox.get(timeout=10))
        extra = {k: v for kind, *rest in items if kind == "extra" for k, v in rest[0].items()}
        # the end of the stream is not slowed (where this process may raise a thread's priority again)
        assert extra["worker_niceness_at_end"] == (0 if _may_raise_priority() else 19)
        assert extra["worker_idle_at_end"] is (IDLE_POLICY and not _may_raise_priority())
    finally:
        worker.stop()
    assert not worker.alive()


def test_renicing_a_process_tree_reaches_its_threads_and_children():
    import multiprocessing

    from canopy.loop.priority import set_tree_niceness

    mp = multiprocessing.get_context("fork")
    parent, child = mp.Pipe(duplex=False)
    go = mp.Event()
    p = mp.Process(target=_tree, args=(child, go))
    p.start()
    try:
        pids = parent.recv()                      # (its own thread, its child process), both at 19
        assert all(thread_niceness(t) == 19 for t in pids)
        assert set_tree_niceness(p.pid, 3) >= 2
        assert all(thread_niceness(t) == 3 for t in pids)
        if IDLE_POLICY:   # the scheduling policy goes along when asked
            set_tree_niceness(p.pid, 19, idle=True)
            assert all(thread_idle(t) for t in pids) and all(thread_niceness(t) == 19 for t in pids)
            set_tree_niceness(p.pid, 3, idle=False)
            assert not any(thread_idle(t) for t in pids) and all(thread_niceness(t) == 3 for t in pids)
    finally:
        go.set()
        p.join(10)


def _tree(conn, go):
    import multiprocessing
    set_thread_niceness(19)
    c = multiprocessing.get_context("fork").Process(target=go.wait, args=(10,))
    c.start()
    conn.send((threading.get_native_id(), c.pid))
    go.wait(10)
    c.join(10)


def _may_raise_priority() -> bool:
    box = {}

    def probe():
        set_thread_niceness(19)
        box["ok"] = set_thread_niceness(0)

    t = threading.Thread(target=probe)
    t.start()
    t.join()
    return box["ok"]


def test_a_forked_helper_dies_with_its_sigkilled_parent(tmp_path):
    """The loop worker and its full-BA child call exit_with_parent: a SIGKILLed loop-closing
    actor must not leave them running (they would hold the launcher's pipes and a core)."""
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "middle.py"
    script.write_text(
        "import os, sys, time\n"
        "from canopy.loop.priority import exit_with_parent\n"
        "parent = os.getpid()\n"
        "pid = os.fork()\n"
        "if pid == 0:\n"
        "    exit_with_parent(parent)\n"
        "    time.sleep(60)\n"
        "    os._exit(0)\n"
        "print(pid, flush=True)\n"
        "time.sleep(60)\n")
    root = str(Path(__file__).resolve().parents[1])
    # the script lives in tmp_path: the checkout goes on its path (an editable install may point elsewhere)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    middle = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=root, env=env)
    helper = int(middle.stdout.readline())
    time.sleep(0.3)  # the helper has called prctl
    os.kill(middle.pid, signal.SIGKILL)
    middle.wait(10)
    def state() -> str:  # Z: dead, waiting for init to reap it
        try:
            return Path(f"/proc/{helper}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return "gone"

    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and state() not in ("gone", "Z"):
        time.sleep(0.05)
    assert state() in ("gone", "Z"), f"the helper outlived its parent (state {state()})"


def test_idle_policy_is_per_thread_and_inherited_by_a_fork():
    from canopy.loop.priority import set_thread_idle

    if not IDLE_POLICY:
        pytest.skip("no SCHED_IDLE on this platform")
    box = _fork_from_a_lowered_thread(lambda: set_thread_idle(True), thread_idle)
    assert box == {"set": True, "mine": True, "child": True}
    assert not thread_idle()                    # the caller's thread keeps SCHED_OTHER
    assert not set_thread_idle(True, 2**22 + 12345)   # no such thread: False, no exception


@pytest.mark.parametrize("process", [True, False])
def test_loop_worker_answers_wake_a_poll_on_its_outbox_fd(process):
    """The loop-closing actor blocks on ``outbox_fd`` (actors.runtime ``wait_fds``) instead of
    polling the queue: the worker process's first answer must make that fd readable; a thread
    worker has no fd and the actor keeps polling it (``next_tick_s`` = OUTBOX_POLL_S)."""
    import zmq

    from actors.loop_closing import OUTBOX_POLL_S, LoopClosingActor
    from canopy.loop.closer import LoopCloser
    from canopy.loop.params import LoopParams
    from canopy.loop.worker import LoopWorker
    from shared.types import StereoCalibration

    calib = StereoCalibration(fx=450.0, fy=450.0, cx=376.0, cy=240.0, baseline=0.11, width=752, height=480)
    worker = LoopWorker(LoopCloser(calib, LoopParams(), None), None, niceness=0, process=process)
    actor = LoopClosingActor({"params": LoopParams()})
    actor.worker = worker
    if not process:
        assert worker.outbox_fd() is None and actor.wait_fds() == []
        assert actor.next_tick_s() == OUTBOX_POLL_S
        return
    fd = worker.outbox_fd()
    assert actor.wait_fds() == [fd] and actor.next_tick_s() is None   # nothing yet: block
    poller = zmq.Poller()
    poller.register(fd, zmq.POLLIN)
    assert poller.poll(0) == []
    worker.start()
    try:
        assert poller.poll(30_000) == [(fd, zmq.POLLIN)]   # the worker's start-up "extra"
        assert actor.next_tick_s() == 0.0
        assert worker.outbox.get(timeout=5)[0] == "extra"
    finally:
        worker.stop()
