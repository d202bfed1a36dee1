"""Starts the actors, watches them, and always cleans up.

The supervisor owns the shared-memory rings and the ipc:// socket folder. It
starts each actor as its own OS process, waits for every ``ready`` message
(never a sleep), tells the source to start, then relays events to the run's
collector while watching for trouble: an actor that exits with an error, is
killed, or stops sending its once-a-second heartbeat ends the run. Whatever
happens (normal end, Ctrl-C, SIGTERM, a killed actor) the rings are
unlinked, the socket folder removed and the remaining actors stopped within
the grace period, so what was computed so far can still be written out.

Every event is also re-published on an optional inspection endpoint
(multipart ``[kind, payload]``, framed by ``run_start`` / ``run_end``) with a
request/reply channel beside it (status, config, stats, map, pause, resume,
save_map, stop); see ``actors.inspection`` for its safety rules.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import shutil
import signal
import tempfile
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable

from pathlib import Path

import psutil
import zmq

from actors.inspection import InspectionServer, ServerKeys, inspection_client  # noqa: F401 (re-export)
from actors.runtime import ActorSpec, actor_main
from protocol.codec import decode, encode
from protocol.messages import (ActorError, ActorReady, ActorStats, Pause, Resume, RunEnd, RunStart, SaveMapRequest,
                               Shutdown, Start)
from shared.errors import ProtocolError
from shared.ring import FrameRing, remove_segment

RUN_DIR_PREFIX = "canopy-"
MAX_SAVED_MAPS = 20           # remote save_map requests per run: a client cannot fill the disk
OWNER_FILE = "owner"          # "<pid> <process create time>" of the launcher that made the folder
SHM_PREFIX = "canopy_"        # ring names are canopy_<launcher pid>_<ms>_<raw|enh>


def _owner_alive(pid: int, create_time: float | None) -> bool:
    try:
        proc = psutil.Process(pid)
        # A recycled pid belongs to another process: compare the start time too.
        return create_time is None or abs(proc.create_time() - create_time) < 1.0
    except psutil.Error:
        return False


def sweep_stale_runs(tmp_dir: str | None = None, shm_dir: str = "/dev/shm") -> list[str]:
    """Remove socket folders and shared-memory rings left by launchers that died without
    cleaning up (SIGKILL). Only folders with an owner file and rings named after a pid are
    touched, and only when that process is gone. Returns what was removed."""
    removed = []
    root = Path(tmp_dir or tempfile.gettempdir())
    for folder in root.glob(f"{RUN_DIR_PREFIX}*"):
        try:
            pid, ctime = folder.joinpath(OWNER_FILE).read_text().split()
            alive = _owner_alive(int(pid), float(ctime))
        except (OSError, ValueError):
            continue  # not ours, or being created right now
        if not alive:
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(str(folder))
    if os.path.isdir(shm_dir):
        for name in os.listdir(shm_dir):
            parts = name.split("_")
            if name.startswith(SHM_PREFIX) and len(parts) >= 3 and parts[1].isdigit() \
                    and not _owner_alive(int(parts[1]), None):
                if remove_segment(name):
                    removed.append(f"{shm_dir}/{name}")
    return removed


@dataclass
class RingSpec:
    name: str
    n_slots: int
    height: int
    width: int
    n_images: int = 2


@dataclass
class RunOutcome:
    ok: bool
    reason: str = ""
    failed_actor: str | None = None
    interrupted: bool = False
    wall_s: float = 0.0
    exit_codes: dict = field(default_factory=dict)


class _Terminate(BaseException):
    """SIGTERM of the launcher, raised wherever the main thread is. A BaseException like
    KeyboardInterrupt, so that no ``except Exception`` on the way (the inspection stream's
    preview fallback, a callback's guard) can swallow it and let the run go on to a normal end:
    CI once saw a SIGTERM during a published event end with exit code 0."""


@dataclass
class HeldSignals:
    received: list = field(default_factory=list)


@contextmanager
def hold_signals(*signums: int):
    """Defer these signals while the block runs (a run's cleanup and the writing of its
    outputs): a SIGTERM or Ctrl-C that lands there is noted in ``received`` instead of killing
    the launcher half-way through ``trajectory.tum`` or leaving the actors orphaned; the caller
    then reports the run as interrupted. Off the main thread (where Python cannot install
    handlers) nothing is held."""
    held = HeldSignals()
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    old = {s: signal.getsignal(s) for s in signums}
    for s in signums:
        signal.signal(s, lambda signum, frame: held.received.append(signum))
    try:
        yield held
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _signal_name(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class Supervisor:
    def __init__(self, actors: list[ActorSpec], rings: list[RingSpec], source: str,
                 on_event: Callable[[Any], None], heartbeat_timeout_s: float = 5.0,
                 ready_timeout_s: float = 60.0, grace_s: float = 1.0,
                 inspect_endpoint: str | None = None, run_dir: str | None = None,
                 inspect_keys: ServerKeys | None = None, run_start: RunStart | None = None,
                 queries: dict[str, Callable[[], dict]] | None = None,
                 inspect_frames_ring: str | None = None, save_map_dir: str | None = None):
        self.specs = actors
        self.ring_specs = rings
        self.source = source
        self.on_event = on_event
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.ready_timeout_s = ready_timeout_s
        self.grace_s = grace_s
        self.inspect_endpoint = inspect_endpoint
        self.run_dir = run_dir
        self.procs: dict[str, mp.Process] = {}
        self.rings: list[FrameRing] = []
        self.last_seen: dict[str, float] = {}
        self.finished: set[str] = set()
        self.inspect_keys = inspect_keys
        self.run_start = run_start
        self.run_id = run_start.run_id if run_start is not None else ""
        self.queries = dict(queries or {})
        self.stop_requested: str | None = None
        self._t_start = time.monotonic()
        self.inspect_frames_ring = inspect_frames_ring  # enhanced ring: JPEG previews for clients
        self.save_map_dir = save_map_dir                # where a remote save_map request writes
        self.paused = False
        self.maps_requested = 0
        self._controls: dict[str, zmq.Socket] = {}

    # -- wiring helpers -----------------------------------------------------------------
    @staticmethod
    def make_run_dir() -> str:
        """A fresh socket folder, tagged with its owner so a later run can sweep it if the
        owner died without cleaning up (SIGKILL of the launcher)."""
        sweep_stale_runs()
        # Short path: ipc:// endpoints must fit in a sockaddr_un (~107 bytes).
        run_dir = tempfile.mkdtemp(prefix=RUN_DIR_PREFIX)
        me = psutil.Process()
        Path(run_dir, OWNER_FILE).write_text(f"{me.pid} {me.create_time():.3f}\n")
        return run_dir

    @staticmethod
    def endpoints(run_dir: str, name: str) -> tuple[str, str]:
        return f"ipc://{run_dir}/{name}.in", f"ipc://{run_dir}/{name}.ctl"

    # -- main ------------------------------------------------------------------------------
    def run(self) -> RunOutcome:
        t_start = self._t_start = time.monotonic()
        outcome = RunOutcome(ok=False)
        zctx = zmq.Context()
        events = zctx.socket(zmq.PULL)
        inspect = None
        controls: dict[str, zmq.Socket] = {}
        self._controls = controls  # remote pause / resume / save_map requests send on these
        frames = None
        old_term = signal.getsignal(signal.SIGTERM)

        def on_term(signum, frame):
            raise _Terminate()

        signal.signal(signal.SIGTERM, on_term)
        try:
            events.bind(self.specs[0].events)
            if self.inspect_endpoint:
                if self.inspect_frames_ring:
                    from actors.frame_preview import RingFrames
                    frames = RingFrames(self.inspect_frames_ring)
                inspect = InspectionServer(zctx, self.inspect_endpoint, self.inspect_keys, frames=frames)
                if self.run_start is not None:
                    inspect.publish(RunStart.KIND, encode(self.run_start))
            for rs in self.ring_specs:
                remove_segment(rs.name)  # a stale segment from a crashed run of the same name
                self.rings.append(FrameRing.create(rs.name, rs.n_slots, rs.height, rs.width, rs.n_images))
            spawn = mp.get_context("spawn")
            for spec in self.specs:
                proc = spawn.Process(target=actor_main, args=(spec,), name=f"canopy-{spec.name}", daemon=False)
                proc.start()
                self.procs[spec.name] = proc
                ctl = zctx.socket(zmq.PUSH)
                ctl.setsockopt(zmq.LINGER, 500)
                ctl.connect(spec.control)
                controls[spec.name] = ctl
            outcome = self._supervise(events, inspect, controls)
        except (KeyboardInterrupt, _Terminate):
            outcome = RunOutcome(ok=False, reason="interrupted by the user", interrupted=True)
        finally:
            try:  # SIGTERM or Ctrl-C while the actors stop: stop them now instead of waiting
                self._stop_all(controls, outcome.reason or "run finished")
            except (KeyboardInterrupt, _Terminate):
                self._kill_all()
            # From here on a SIGTERM goes where the caller put it (app.run_slam holds it until
            # the outputs are written); raising it in the cleanup below would leak the rings.
            signal.signal(signal.SIGTERM, old_term)
            outcome.exit_codes = {n: p.exitcode for n, p in self.procs.items()}
            self._drain(events, inspect)
            if inspect is not None:
                inspect.publish(RunEnd.KIND, encode(RunEnd(run_id=self.run_id, ok=outcome.ok,
                                                           reason=outcome.reason or "run finished",
                                                           wall_s=time.monotonic() - t_start)))
                inspect.close()  # lingers 0.5 s so run_end reaches connected clients
            if frames is not None:
                frames.close()
            for sock in [events, *controls.values()]:
                sock.close(linger=0)
            zctx.term()
            for ring in self.rings:
                ring.close()
                ring.unlink()
            if self.run_dir:
                shutil.rmtree(self.run_dir, ignore_errors=True)
            outcome.wall_s = time.monotonic() - t_start
        return outcome

    def _dispatch(self, payload: bytes, inspect) -> Any:
        try:
            msg = decode(payload)
        except ProtocolError as exc:
            self.on_event(ActorError(actor="supervisor", error=f"malformed event dropped: {exc}"))
            return None
        # Record first, then publish: a signal that interrupts between the two must never leave a
        # remote client holding a pose that the run's own outputs do not have.
        self.on_event(msg)
        if inspect is not None:
            inspect.publish_event(msg, payload)
        return msg

    def _drain(self, events, inspect) -> None:
        while events.poll(0):
            self._dispatch(events.recv(), inspect)

    def _supervise(self, events, inspect, controls) -> RunOutcome:
        ready: set[str] = set()
        deadline = time.monotonic() + self.ready_timeout_s
        while len(ready) < len(self.specs):
            if inspect is not None:
                inspect.serve(self._answer, self.run_id)
            if self.stop_requested:
                return RunOutcome(False, self.stop_requested, interrupted=True)
            if events.poll(100):
                msg = self._dispatch(events.recv(), inspect)
                if isinstance(msg, ActorReady):
                    ready.add(msg.actor)
                    self.last_seen[msg.actor] = time.monotonic()
                elif isinstance(msg, ActorStats) and msg.actor in ready:
                    # an actor ready early keeps beating while the others import: without this its
                    # last sign of life stays at its ready time, and on a loaded machine (others
                    # ready > heartbeat_timeout_s later) it was called hung on the first check
                    self.last_seen[msg.actor] = time.monotonic()
                elif isinstance(msg, ActorError):
                    return RunOutcome(False, f"actor '{msg.actor}' failed during set-up: {msg.error}", msg.actor)
            dead = self._dead_actor()
            if dead:
                return dead
            if time.monotonic() > deadline:
                missing = sorted({s.name for s in self.specs} - ready)
                return RunOutcome(False, f"actors not ready after {self.ready_timeout_s:.0f} s: {missing}")
        controls[self.source].send(encode(Start()))
        while True:
            if inspect is not None:
                inspect.serve(self._answer, self.run_id)
            if self.stop_requested:
                return RunOutcome(False, self.stop_requested, interrupted=True)
            if events.poll(100):
                while True:
                    msg = self._dispatch(events.recv(), inspect)
                    if isinstance(msg, ActorStats):
                        self.last_seen[msg.actor] = time.monotonic()
                        if msg.final:
                            self.finished.add(msg.actor)
                    elif isinstance(msg, ActorError):
                        where = f" at frame {msg.frame_index}" if msg.frame_index >= 0 else ""
                        return RunOutcome(False, f"actor '{msg.actor}' failed{where}: {msg.error}", msg.actor)
                    if not events.poll(0):
                        break
            dead = self._dead_actor()
            if dead:
                return dead
            if all(not p.is_alive() for p in self.procs.values()):
                return RunOutcome(True, "completed")
            silent = self._silent_actors()
            if silent:
                return self._blame(silent)

    def _answer(self, command: str) -> tuple[dict, str | None]:
        """A remote client's request (actors.inspection.COMMANDS)."""
        if command == "stop":
            self.stop_requested = "stopped by a remote client"
            return {"stopping": True}, None
        if command in ("pause", "resume"):
            return self._control("source", Pause() if command == "pause" else Resume(),
                                 {"paused": command == "pause"}, lambda: setattr(self, "paused", command == "pause"))
        if command == "save_map":
            if not self.save_map_dir:
                return {}, "'save_map' is not available in this run"
            if self.maps_requested >= MAX_SAVED_MAPS:
                return {}, f"at most {MAX_SAVED_MAPS} maps are saved per run"
            self.maps_requested += 1
            path = str(Path(self.save_map_dir) / f"map-{self.maps_requested:03d}.canopy")
            # the answer comes as a map_saved event once local mapping wrote the file
            return self._control("local_mapping", SaveMapRequest(path=path), {"path": path, "event": "map_saved"})
        if command == "status":
            base = {"run_id": self.run_id, "paused": self.paused, "uptime_s": time.monotonic() - self._t_start,
                    "actors": {n: ("finished" if n in self.finished else
                                   "alive" if p.is_alive() else _signal_name(p.exitcode))
                               for n, p in self.procs.items()}}
            extra = self.queries.get("status")
            return ({**base, **extra()} if extra else base), None
        query = self.queries.get(command)
        if query is None:
            return {}, f"{command!r} is not available in this run"
        return query(), None

    def _control(self, actor: str, msg, payload: dict, on_sent=lambda: None) -> tuple[dict, str | None]:
        sock = self._controls.get(actor)
        proc = self.procs.get(actor)
        if sock is None or proc is None or not proc.is_alive() or actor in self.finished:
            return {}, f"actor {actor!r} is not running"
        try:
            sock.send(encode(msg), zmq.NOBLOCK)
        except zmq.ZMQError as exc:
            return {}, f"actor {actor!r} did not take the request: {exc}"
        on_sent()
        return payload, None

    def _silent_actors(self) -> dict[str, float]:
        """Actors whose last heartbeat is older than the timeout: {name: seconds silent}."""
        now = time.monotonic()
        return {name: now - seen for name, seen in self.last_seen.items()
                if name not in self.finished and now - seen > self.heartbeat_timeout_s}

    def _blame(self, silent: dict[str, float]) -> RunOutcome:
        """Name the actor that hangs. An actor blocked waiting on another one keeps sending
        heartbeats (ActorContext.recv_inbox), but several may still fall silent together: a
        stopped process (SIGSTOP, a debugger) is the culprit, else the one silent longest."""
        for name in silent:
            proc = self.procs.get(name)
            try:
                stopped = proc is not None and psutil.Process(proc.pid).status() in (
                    psutil.STATUS_STOPPED, psutil.STATUS_TRACING_STOP)
            except psutil.Error:
                stopped = False
            if stopped:
                return RunOutcome(False, f"actor '{name}' is frozen (process stopped, e.g. by SIGSTOP): "
                                         f"no heartbeat for {silent[name]:.1f} s", name)
        name = max(silent, key=silent.get)
        return RunOutcome(False, f"actor '{name}' sent no heartbeat for {silent[name]:.1f} s (hung?)", name)

    def _dead_actor(self) -> RunOutcome | None:
        for name, proc in self.procs.items():
            code = proc.exitcode
            if code is not None and code != 0:
                return RunOutcome(False, f"actor '{name}' died ({_signal_name(code)})", name)
        return None

    def _stop_all(self, controls, reason: str) -> None:
        for name, proc in self.procs.items():
            if proc.is_alive() and name in controls:
                try:
                    controls[name].send(encode(Shutdown(reason=reason)), zmq.NOBLOCK)
                except zmq.ZMQError:
                    pass
        deadline = time.monotonic() + self.grace_s
        for proc in self.procs.values():
            proc.join(max(0.0, deadline - time.monotonic()))
        for proc in self.procs.values():
            if proc.is_alive():
                proc.terminate()
        deadline = time.monotonic() + 0.5
        for proc in self.procs.values():
            proc.join(max(0.0, deadline - time.monotonic()))
        self._kill_all()

    def _kill_all(self) -> None:
        for proc in self.procs.values():
            if proc.is_alive():
                proc.kill()
                proc.join(1.0)
