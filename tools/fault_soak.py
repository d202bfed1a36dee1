#!/usr/bin/env python
"""Fault soak (issue 11): many short runs, each hit by one fault, then a count of what was left.

Faults cycle through: none, SIGKILL of each actor (source, enhancement, tracking, local_mapping,
recorder), SIGKILL of the launcher, SIGSTOP of local mapping, Ctrl-C of the process group and
SIGTERM of the launcher. Every fault waits for a progress event on the run's inspection
endpoint (a pose of frame 10 or later). After each run: shared-memory rings named after its
launcher, its socket folder, and actor processes still alive are counted (a launcher killed with SIGKILL
cannot clean up: its folder must be swept by the next run's start-up, counted at the end).

    python tools/fault_soak.py --runs 30            # prints a table, writes docs/results/fault_soak.json
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from actors.supervisor import OWNER_FILE, RUN_DIR_PREFIX, inspection_client  # noqa: E402
from protocol.messages import ActorReady, FramePose  # noqa: E402

FAULTS = ["none", "kill:source", "kill:enhancement", "kill:tracking", "kill:local_mapping", "kill:recorder",
          "kill:launcher", "stop:local_mapping", "ctrl-c", "sigterm"]
WAIT_FOR_POSED = 10  # frame index the fault waits for


def _run_dirs_of(pid: int) -> list[Path]:
    out = []
    for d in Path(tempfile.gettempdir()).glob(f"{RUN_DIR_PREFIX}*"):
        try:
            if (d / OWNER_FILE).read_text().split()[0] == str(pid):
                out.append(d)
        except (OSError, IndexError):
            pass
    return out


def _segments_of(pid: int) -> list[str]:
    return [n for n in os.listdir("/dev/shm") if n.startswith(f"canopy_{pid}_")]


def _alive(pids) -> list[int]:
    return [p for p in pids if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]


def one_run(k: int, fault: str, work: Path, config: Path) -> dict:
    endpoint = f"ipc://{work}/inspect{k}"
    cmd = [sys.executable, str(ROOT / "launch.py"), "--dataset", "euroc", "--clock", "realtime", "--quiet",
           "--config", str(config), "--out", str(work / f"run{k}"), "--inspect", endpoint, "--record"]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    pids, posed, injected = {}, 0, False
    try:
        for msg in inspection_client(endpoint, ["ready", "pose"], timeout_s=120, until_run_end=True):
            if isinstance(msg, ActorReady):
                pids[msg.actor] = msg.pid
            elif isinstance(msg, FramePose):
                posed += msg.status in ("init", "ok")
                # by index, not by count: a busy machine makes realtime drop frames
                if msg.index >= WAIT_FOR_POSED:
                    what, _, who = fault.partition(":")
                    if fault == "none":
                        pass  # let the run finish
                    elif what == "kill" and who == "launcher":
                        proc.kill()
                    elif what == "kill":
                        os.kill(pids[who], signal.SIGKILL)
                    elif what == "stop":
                        os.kill(pids[who], signal.SIGSTOP)
                    elif fault == "ctrl-c":
                        os.killpg(proc.pid, signal.SIGINT)
                    else:
                        proc.send_signal(signal.SIGTERM)
                    injected = True
                    break
        _, stderr = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    deadline = time.monotonic() + 30  # actors of a killed launcher notice within ~0.1 s
    while _alive(pids.values()) and time.monotonic() < deadline:
        time.sleep(0.2)
    return {"run": k, "fault": fault, "injected": injected or fault == "none", "exit_code": proc.returncode,
            "wall_s": round(time.monotonic() - t0, 2), "posed_before_fault": posed,
            "traceback": "Traceback" in stderr,
            "last_error_line": next((ln for ln in reversed(stderr.splitlines()) if ln.startswith("error:")), ""),
            "launcher_pid": proc.pid, "leaked_processes": len(_alive(pids.values())),
            "leaked_segments": len(_segments_of(proc.pid)), "socket_dirs_after_run": len(_run_dirs_of(proc.pid))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--json", default=str(ROOT / "docs" / "results" / "fault_soak.json"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="soak") as tmp:
        work = Path(tmp)
        config = work / "soak.yaml"  # a frozen actor is named after 3 s instead of 5
        config.write_text((ROOT / "configs" / "euroc.yaml").read_text().replace(
            "heartbeat_timeout_s: 5.0", "heartbeat_timeout_s: 3.0"))
        rows = [one_run(k, FAULTS[k % len(FAULTS)], work, config) for k in range(args.runs)]
        for r in rows:
            print(f"{r['run']:3d} {r['fault']:20s} exit {r['exit_code']!s:>3} {r['wall_s']:6.1f} s  "
                  f"procs {r['leaked_processes']} shm {r['leaked_segments']} dirs {r['socket_dirs_after_run']}  "
                  f"{r['last_error_line'][:70]}")
        # One more (clean) start sweeps the folders of killed launchers.
        from actors.supervisor import Supervisor
        import shutil
        shutil.rmtree(Supervisor.make_run_dir(), ignore_errors=True)
        left = {"socket_dirs": sum(len(_run_dirs_of(r["launcher_pid"])) for r in rows),
                "segments": sum(len(_segments_of(r["launcher_pid"])) for r in rows),
                "processes": sum(r["leaked_processes"] for r in rows),
                "tracebacks": sum(r["traceback"] for r in rows),
                "not_injected": sum(not r["injected"] for r in rows)}
    print(f"\n{args.runs} runs: left behind {left}")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"runs": rows, "left_behind": left, "cpu_count": os.cpu_count(),
                                           "note": "machine shared with other jobs; wall times are noisy"},
                                          indent=2) + "\n")
    return 0 if not any(left.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
