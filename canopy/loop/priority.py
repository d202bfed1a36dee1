"""CPU priority of the loop closer's work (issue 10: "the loop closer never delays tracking").

The loop closer's answers are applied whenever they arrive, so its work (database query,
verification, pose graph, full BA) can wait for free cores; the loop-closing actor's message
loop and heartbeat cannot (the supervisor ends a run whose actor misses heartbeats). So the
work runs in a worker thread niced alone, and the actor's main thread keeps the normal priority.

On Linux the nice value is a per-thread attribute: ``setpriority(PRIO_PROCESS, tid, n)`` with
a thread id (``threading.get_native_id()``) renices that thread only (setpriority(2), NOTES),
and a process forked from the thread starts with its nice value. Elsewhere these helpers change
nothing and say so (their return value).
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading

from shared.errors import ConfigError

PER_THREAD = sys.platform.startswith("linux")  # nice values are per thread only on Linux


def _check(niceness: int) -> int:
    n = int(niceness)
    if not -20 <= n <= 19:
        raise ConfigError("niceness", f"must be in [-20, 19] (got {niceness!r})")
    return n


def thread_niceness(tid: int | None = None) -> int | None:
    """Nice value of thread ``tid`` (default: the calling thread); None where not per-thread."""
    if not PER_THREAD:
        return None
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id() if tid is None else int(tid))


def set_thread_niceness(niceness: int, tid: int | None = None) -> bool:
    """Set the nice value of one thread (default: the calling thread), leaving the process's
    other threads as they are. Raising the priority again (a lower value) needs CAP_SYS_NICE
    or RLIMIT_NICE; returns False when it was not allowed or the platform has no per-thread
    nice value, True when set."""
    n = _check(niceness)
    if not PER_THREAD:
        return False
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id() if tid is None else int(tid), n)
    except (PermissionError, ProcessLookupError):
        return False
    return True


def thread_idle(tid: int | None = None) -> bool | None:
    """Whether thread ``tid`` (default: the calling thread) runs under SCHED_IDLE; None where the
    platform has no scheduling policies."""
    if not hasattr(os, "sched_getscheduler"):
        return None
    try:
        return os.sched_getscheduler(threading.get_native_id() if tid is None else int(tid)) == os.SCHED_IDLE
    except OSError:
        return None


def set_thread_idle(idle: bool, tid: int | None = None) -> bool:
    """Put one thread (default: the calling thread) under SCHED_IDLE, or back under SCHED_OTHER.

    A nice value alone does not keep a background thread off tracking's cores: the kernel's fair
    scheduler (EEVDF since Linux 6.6) protects a running task from wakeup preemption until it has
    used its slice (RUN_TO_PARITY), whatever its weight, so each time the tracking thread or its
    stereo worker woke onto a core the nice-19 loop worker held, it waited up to a slice (~3 ms),
    several times per frame. A SCHED_IDLE task is preempted at once by any normal task that wakes
    (sched(7), SCHED_IDLE; kernel/sched/fair.c, "preempt an idle entity in favor of a non-idle
    entity"). Threads and processes it creates inherit the policy. Returns False where not
    allowed (leaving SCHED_IDLE again needs the nice value within RLIMIT_NICE) or unsupported.
    """
    if not hasattr(os, "sched_setscheduler"):
        return False
    try:
        os.sched_setscheduler(threading.get_native_id() if tid is None else int(tid),
                              os.SCHED_IDLE if idle else os.SCHED_OTHER, os.sched_param(0))
    except (PermissionError, ProcessLookupError, OSError):
        return False
    return True


def set_process_niceness(pid: int, niceness: int) -> bool:
    """Set the nice value of a (single-threaded) child process, e.g. the full-BA child; False
    if not allowed or the process is gone."""
    n = _check(niceness)
    try:
        os.setpriority(os.PRIO_PROCESS, int(pid), n)
    except (PermissionError, ProcessLookupError, OSError):
        return False
    return True


def set_tree_niceness(pid: int, niceness: int, idle: bool | None = None) -> int:
    """Set the nice value of every thread of process ``pid`` and of its descendants (Linux
    /proc: ``task/<tid>/children``), e.g. the loop closer's worker process and its full-BA child;
    with ``idle`` given, their scheduling policy too (SCHED_IDLE or SCHED_OTHER, see
    ``set_thread_idle``). Returns the number of threads whose nice value was set."""
    n = _check(niceness)
    if not PER_THREAD:
        return 0
    done, todo, seen = 0, [int(pid)], set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        try:
            tids = [int(t) for t in os.listdir(f"/proc/{p}/task")]
        except OSError:
            continue
        for t in tids:
            if idle is False:  # SCHED_OTHER first: SCHED_IDLE ignores the nice value
                set_thread_idle(False, t)
            done += set_thread_niceness(n, t)
            if idle:
                set_thread_idle(True, t)
            try:
                with open(f"/proc/{p}/task/{t}/children") as f:
                    todo.extend(int(c) for c in f.read().split())
            except OSError:
                pass
    return done


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def exit_with_parent(parent_pid: int) -> None:
    """Have the kernel SIGKILL this process when the thread that forked it dies.

    The loop worker and its full-BA child are forked helpers of the loop-closing actor: when the
    actor is SIGKILLed (or killed by the supervisor after an actor died) nothing else would stop
    them, and a helper that lingers holds the launcher's stdout/stderr pipes open (a caller
    waiting for them to close hangs) and a core. Polling ``getppid`` alone is too late: a helper
    busy in a long step, or blocked flushing a queue nobody reads any more, never gets there.
    Linux only; elsewhere nothing happens.
    """
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(0)
