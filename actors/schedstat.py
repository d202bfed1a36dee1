"""Per-thread CPU time and run-queue wait of this process, from Linux's scheduler statistics
(``/proc/self/task/<tid>/schedstat``: time on a CPU, time runnable but waiting for one, in ns).

The run-queue wait says whether a thread was held up for want of a free core (on a shared 2-core
machine, tracking's thread competes with local mapping, the feeders and other programs): CPU time
shows what a stage costs, the wait what the machine added. Where /proc is missing (not Linux) the
readings are empty and nothing is reported.
"""
from __future__ import annotations

import os
from pathlib import Path

TASKS = Path("/proc/self/task")


def thread_schedstat() -> dict[int, tuple[int, int]]:
    """{thread id: (ns on a CPU, ns waiting on a run queue)} of every thread of this process."""
    out = {}
    try:
        tids = os.listdir(TASKS)
    except OSError:
        return out
    for tid in tids:
        try:
            run_ns, wait_ns = (TASKS / tid / "schedstat").read_text().split()[:2]
        except (OSError, ValueError):
            continue  # the thread ended meanwhile, or no schedstat in this kernel
        out[int(tid)] = (int(run_ns), int(wait_ns))
    return out


def thread_report(start: dict[int, tuple[int, int]], end: dict[int, tuple[int, int]],
                  names: dict[int, str], n_frames: int) -> dict:
    """CPU and run-queue wait between two readings, per named thread (the rest summed as "other"),
    in seconds and in ms per frame."""
    rows: dict[str, list[float]] = {}
    for tid, (run_ns, wait_ns) in end.items():
        run0, wait0 = start.get(tid, (0, 0))
        row = rows.setdefault(names.get(tid, "other"), [0.0, 0.0])
        row[0] += (run_ns - run0) * 1e-9
        row[1] += (wait_ns - wait0) * 1e-9
    per = max(n_frames, 1)
    return {name: {"cpu_s": round(cpu, 4), "runqueue_wait_s": round(wait, 4),
                   "cpu_ms_per_frame": round(cpu * 1e3 / per, 3), "runqueue_wait_ms_per_frame": round(wait * 1e3 / per, 3)}
            for name, (cpu, wait) in sorted(rows.items())}
