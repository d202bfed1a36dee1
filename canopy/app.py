"""Runs one SLAM session: source → enhancement → tracking → local mapping.

``run_slam`` is what ``launch.py`` calls and what tests and benchmarks call:
it validates everything it can before any process starts (dataset, config,
image size), wires the actors, runs the supervisor, and always writes what
was computed to the output folder.
"""
from __future__ import annotations

import os
import signal
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from actors.collector import RunCollector, format_summary
from actors.runtime import ActorSpec
from actors.supervisor import RingSpec, RunOutcome, Supervisor, hold_signals
from canopy.config import REPO_ROOT, load_run_config, with_overrides
from canopy.sources import open_source

DATASETS = ("euroc", "kitti", "folder", "synthetic")
# Generated sequences are cached here (override with CANOPY_CACHE_DIR, e.g. on a bigger disk).
SYNTHETIC_CACHE_ENV = "CANOPY_CACHE_DIR"


def synthetic_cache_dir() -> Path:
    return Path(os.environ.get(SYNTHETIC_CACHE_ENV, REPO_ROOT / "cache")) / "synthetic"


def prepare_synthetic(preset: str | None, n_frames: int | None, seed: int, progress: bool) -> str:
    """Generate (or reuse from the cache) a synthetic orchard sequence; return its EuRoC folder."""
    import sys

    from canopy.synthetic import PRESETS, generate_sequence
    from shared.errors import ConfigError

    preset = preset or "day-loop"
    if preset not in PRESETS:
        raise ConfigError("--preset", f"unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
    folder = synthetic_cache_dir() / f"{preset}-seed{seed}-{n_frames if n_frames else 'full'}"

    def report(done: int, total: int) -> None:
        if progress and (done == total or done % 50 == 0):
            sys.stderr.write(f"\r  generating {preset}: {done}/{total} frames")
            sys.stderr.write("\n" if done == total else "")
            sys.stderr.flush()

    return str(generate_sequence(preset, folder, n_frames=n_frames, seed=seed, progress=report))


@dataclass
class RunResult:
    outcome: RunOutcome
    summary: dict
    out_dir: Path
    text: str


def default_out_dir(dataset: str) -> Path:
    return REPO_ROOT / "results" / f"{dataset}-{time.strftime('%Y%m%d-%H%M%S')}"


def build_actor_specs(run_dir: str, cfg, dataset: str, path: str | None, max_frames: int | None,
                      rings: dict[str, str], calib, frame_rate_hz: float,
                      record: str | None = None, save_map: str | None = None, load_map: str | None = None,
                      localize: bool = False, first_index: int = 0) -> list[ActorSpec]:
    ep = {name: Supervisor.endpoints(run_dir, name)
          for name in ("source", "enhancement", "tracking", "local_mapping", "loop_closing", "recorder")}
    to_recorder = ["recorder"] if record else []
    # mono closes loops in Sim(3) (canopy.loop.mono) unless mono.loop_enabled is off; localisation
    # in a loaded map makes no keyframes to close loops with
    loop_on = (cfg.loop is not None and cfg.loop.enabled and not localize
               and (cfg.runtime.sensor != "mono" or cfg.mono is None or cfg.mono.loop_enabled))
    to_loop = ["loop_closing"] if loop_on else []
    events = f"ipc://{run_dir}/supervisor.events"
    rt = cfg.runtime
    # In realtime a frame older than max_lag_frames periods is skipped when a newer one waits.
    common = {"clock": rt.clock, "frame_period_s": 1.0 / (frame_rate_hz * rt.realtime_speed),
              "max_lag_frames": rt.max_lag_frames, "malloc_keep_mb": rt.malloc_keep_mb}

    def spec(name, factory, config, outputs):
        return ActorSpec(name=name, factory=factory, config={**common, **config}, inbox=ep[name][0],
                         control=ep[name][1], events=events, outputs={o: ep[o][0] for o in outputs}, seed=rt.seed)

    return [
        spec("source", "actors.source:SourceActor",
             {"kind": dataset, "path": path, "max_frames": max_frames, "ring": rings["raw"],
              "realtime_speed": rt.realtime_speed, "index_base": first_index,
              "lockstep_prefetch_frames": rt.lockstep_prefetch_frames, "niceness": rt.feeder_niceness},
             ["enhancement"]),
        spec("enhancement", "actors.enhancement:EnhancementActor",
             {"in_ring": rings["raw"], "out_ring": rings["enhanced"], "params": cfg.enhancement,
              "niceness": rt.feeder_niceness}, ["tracking"]),
        spec("tracking", "actors.tracking:TrackingActor",
             {"ring": rings["enhanced"], "calib": calib, "params": cfg.tracking,
              "enhancement": cfg.enhancement, "lockstep_wait_s": rt.lockstep_wait_s,
              "map_update_lag_frames": rt.map_update_lag_frames, "extract_ahead": rt.lockstep_extract_ahead,
              "sensor": rt.sensor, "mono": cfg.mono, "loop": cfg.loop if cfg.runtime.sensor != "mono" else None,
              "load_map": load_map, "localize": localize},
             ["local_mapping", "source", *to_recorder]),
        spec("local_mapping", "actors.local_mapping:LocalMappingActor",
             {"calib": calib, "params": cfg.mapping, "snapshot_period_s": rt.map_snapshot_period_s,
              "lockstep_wait_s": rt.lockstep_wait_s, "save_map": save_map, "load_map": load_map,
              "sensor": rt.sensor, "mono": cfg.mono, "pixel_sigma": cfg.tracking.pixel_sigma,
              "niceness": rt.mapping_niceness,
              "vocabulary_id": Path(cfg.loop.vocabulary).name if loop_on and cfg.loop.vocabulary else
              ("default" if loop_on else "")},
             ["tracking", *to_recorder, *to_loop]),
    ] + ([spec("loop_closing", "actors.loop_closing:LoopClosingActor",
               {"calib": calib, "params": cfg.loop, "sensor": rt.sensor, "mono": cfg.mono, "load_map": load_map},
               ["local_mapping"])] if loop_on else []) + ([spec("recorder", "actors.recorder:RecorderActor",
               {"path": record, "ring": rings["enhanced"], "image_every": 1, "end_of_streams": 2}, [])]
         if record else [])


def run_slam(dataset: str, path: str | None = None, config: str | None = None, out: str | None = None,
             clock: str | None = None, max_frames: int | None = None, enhance: str | None = None,
             inspect: str | None = None, progress: bool = True, preset: str | None = None,
             seed: int = 0, lines: bool | None = None, record: str | None = None,
             inspect_keys: str | None = None, loop: bool | None = None,
             save_map: str | None = None, sensor: str | None = None, load_map: str | None = None,
             localize: bool = False, foxglove: str | None = None) -> RunResult:
    if dataset not in DATASETS:
        from shared.errors import ConfigError
        raise ConfigError("--dataset", f"unknown dataset {dataset!r}; choose one of {DATASETS}")
    cfg = with_overrides(load_run_config(dataset, config), clock=clock, enhance=enhance, lines=lines, loop=loop,
                         sensor=sensor)
    if cfg.loop is not None and cfg.loop.enabled:  # a missing vocabulary is an error before any process starts
        from canopy.loop.vocabulary import check_vocabulary
        check_vocabulary(cfg.loop.vocabulary)
    if dataset == "synthetic":
        # A generated sequence is written in the EuRoC ASL layout and read as such.
        if path is None:
            path = prepare_synthetic(preset, max_frames, seed, progress)
        dataset_kind = "euroc"
    else:
        dataset_kind = dataset
    server_keys = None
    if inspect is not None:
        from actors.inspection import check_inspection
        server_keys = check_inspection(inspect, inspect_keys)  # loopback, or CURVE keys; ports free
    elif inspect_keys is not None:
        from shared.errors import ConfigError
        raise ConfigError("--inspect-keys", "only applies with --inspect")
    if foxglove is not None:  # SDK installed, loopback HOST:PORT: checked before any file or process
        from actors.foxglove_live import check_foxglove
        check_foxglove(foxglove)
    source = open_source(dataset_kind, path, max_frames=max_frames)  # validates the dataset before any process starts
    calib = source.calibration
    load_map_path, first_index = _check_load_map(load_map, localize, calib, cfg)
    out_dir = prepare_out_dir(Path(out) if out else default_out_dir(dataset))
    record_path = None
    if record is not None:  # "" = the default name in the results folder
        from canopy.recording import check_output_path
        record_path = str(check_output_path(Path(record) if record else out_dir / "run.mcap"))
    run_dir = Supervisor.make_run_dir()
    tag = f"canopy_{os.getpid()}_{int(time.time() * 1000) % 100000}"
    rings = {"raw": f"{tag}_raw", "enhanced": f"{tag}_enh"}
    save_map_path = str(Path(save_map).resolve()) if save_map else None
    specs = build_actor_specs(run_dir, cfg, dataset_kind, path, max_frames, rings, calib, source.rate_hz,
                              record=record_path, save_map=save_map_path, load_map=load_map_path,
                              localize=localize, first_index=first_index)
    # trajectory.tum and frames.csv grow as frames complete: a killed launcher still leaves them.
    collector = RunCollector(n_frames=len(source), progress=progress, out_dir=out_dir,
                             frame_stamps=source.timestamps, first_index=first_index)
    run_id = f"{dataset}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
    from canopy.report import to_jsonable
    from protocol.messages import RunStart
    run_start = RunStart(run_id=run_id, dataset=dataset, source=source.name, n_frames=len(source),
                         clock=cfg.runtime.clock, started_at=time.time())
    queries = {
        "status": lambda: {"dataset": dataset, "source": source.name, "out_dir": str(out_dir),
                           "frames_total": len(source), "frames_done": len(collector.poses)},
        "config": lambda: to_jsonable(_config_dict(cfg)),
        "stats": lambda: to_jsonable({"tracking": collector.tracking_summary(), "actors": collector.stats_summary()}),
        "map": lambda: _map_payload(collector.snapshot),
    }
    live = None
    if foxglove is not None:  # Foxglove live view (issue 12): serves before any actor starts, fails fast
        from actors.foxglove_live import start_foxglove
        try:
            live = start_foxglove(foxglove, ring_name=rings["enhanced"], run_id=run_id)
        except Exception:
            import shutil
            shutil.rmtree(run_dir, ignore_errors=True)  # no actor started: nothing else to clean
            raise
        if progress:
            import sys
            print(f"Foxglove: open {live.url} in the Foxglove app (Open connection)", file=sys.stderr)
    on_event = collector if live is None else (lambda msg: (collector(msg), live(msg)))
    supervisor = Supervisor(
        specs, [RingSpec(rings["raw"], cfg.runtime.ring_slots, calib.height, calib.width),
                RingSpec(rings["enhanced"], cfg.runtime.ring_slots, calib.height, calib.width)],
        source="source", on_event=on_event, heartbeat_timeout_s=cfg.runtime.heartbeat_timeout_s,
        ready_timeout_s=cfg.runtime.ready_timeout_s, grace_s=cfg.runtime.grace_s,
        inspect_endpoint=inspect, run_dir=run_dir, inspect_keys=server_keys, run_start=run_start,
        queries=queries, inspect_frames_ring=rings["enhanced"], save_map_dir=str(out_dir))
    # SIGTERM is held from the end of the supervisor's own handling (it raises inside the run)
    # until every output is written, Ctrl-C from the end of the run: a late signal must not cost
    # the user what was computed. Either one still ends the launcher with the run reported
    # interrupted.
    with hold_signals(signal.SIGTERM) as held_term:
        try:
            outcome = supervisor.run()
        finally:
            if live is not None:
                live.close()
        with hold_signals(signal.SIGINT) as held_int:
            result = _write_run_outputs(outcome, collector, cfg, calib, source, out_dir, run_id, dataset, preset,
                                        path, record_path, save_map_path)
    if (held_term.received or held_int.received) and outcome.ok:
        outcome.ok, outcome.interrupted = False, True
        outcome.reason = "interrupted by the user (after the last frame: the results are complete)"
    return result


def _write_run_outputs(outcome, collector, cfg, calib, source, out_dir, run_id, dataset, preset, path,
                       record_path, save_map_path) -> RunResult:
    collector.finish_progress()
    repaired = None
    if record_path and Path(record_path).is_file():
        from canopy.recording import repair_recording
        repaired = repair_recording(record_path)  # the recorder may have died before writing its summary
    run_info = {"run_id": run_id, "launcher_pid": os.getpid(), "dataset": dataset, "preset": preset if dataset == "synthetic" else None,
                "path": str(source.root) if hasattr(source, "root") else path,
                "source": source.name, "clock": cfg.runtime.clock,
                "enhancement": getattr(cfg.enhancement, "method", "none"), "config_file": cfg.source_file,
                "lines": bool(cfg.tracking.use_lines), "recording": record_path, "sensor": cfg.runtime.sensor,
                "recording_repaired_messages": repaired,
                "loop_closing": bool(cfg.loop is not None and cfg.loop.enabled),
                "outcome": outcome.reason, "ok": outcome.ok, "wall_s": outcome.wall_s,
                "frames_per_s": len(collector.poses) / outcome.wall_s if outcome.wall_s else None,
                "failed_actor": outcome.failed_actor,
                "cpu_count": os.cpu_count(), "calibration": calib.to_dict(),
                "errors": [{"actor": e.actor, "error": e.error, "frame": e.frame_index} for e in collector.errors]}
    summary = collector.write_outputs(out_dir, source.ground_truth, run_info)
    if record_path and Path(record_path).is_file():
        summary["files"]["recording"] = record_path
    if save_map_path and Path(save_map_path).is_file():
        summary["files"]["map"] = save_map_path
    _write_config(out_dir, cfg)
    text = format_summary(summary, outcome.reason, os.cpu_count() or 1)
    return RunResult(outcome=outcome, summary=summary, out_dir=out_dir, text=text)


def _check_load_map(load_map: str | None, localize: bool, calib, cfg) -> tuple[str | None, int]:
    """--load-map / --localize checked before any process starts: the map must read, match this
    camera's calibration (one-line error otherwise) and be used by a stereo run. Returns the
    map's path and the number of this run's first frame (after the loaded keyframes when the
    run extends the map, else 0)."""
    from shared.errors import ConfigError

    if load_map is None:
        if localize:
            raise ConfigError("--localize", "needs --load-map PATH (the map to localise in)")
        return None, 0
    if cfg.runtime.sensor == "mono":
        raise ConfigError("--load-map", "loaded maps are stereo maps; not available with --sensor mono")
    from canopy.loop.map_io import first_free_index, load_map as read_map
    data = read_map(load_map, calib)  # InputError naming the file: missing, not a map, other version or calibration
    # extending the map: this run's frames (and so its keyframes) are numbered after the loaded keyframes
    return str(Path(load_map).resolve()), (0 if localize else first_free_index(data))


def _map_payload(snap) -> dict:
    """The ``map`` inspection request: the latest whole map (ids, points, keyframe poses)."""
    import numpy as np

    from actors.inspection_stream import snapshot_ids
    if snap is None:
        return {"point_ids": np.zeros(0, np.int64), "points": np.zeros((0, 3), np.float32),
                "keyframe_indices": np.zeros(0, np.int64), "keyframe_poses": np.zeros((0, 4, 4))}
    return {"point_ids": snapshot_ids(snap), "points": np.asarray(snap.points, np.float32),
            "keyframe_indices": np.asarray(snap.keyframe_indices, np.int64),
            "keyframe_poses": np.asarray(snap.keyframe_poses, np.float64)}


def prepare_out_dir(out_dir: Path) -> Path:
    """Create the results folder before any process starts and prove it is writable, so a bad
    ``--out`` fails in a second with one line instead of after the whole run."""
    from shared.errors import ConfigError

    where = f"--out {out_dir}"
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(where, "is a file, not a folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise ConfigError(where, "cannot create the folder: a parent is a file") from None
    except OSError as exc:
        raise ConfigError(where, f"cannot create the folder: {exc.strerror or exc}") from None
    probe = out_dir / f".canopy-write-test-{os.getpid()}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(where, f"folder is not writable: {exc.strerror or exc}") from None
    return out_dir


def _config_dict(cfg) -> dict:
    return {"runtime": asdict(cfg.runtime), "enhancement": asdict(cfg.enhancement),
            "tracking": asdict(cfg.tracking), "mapping": asdict(cfg.mapping),
            **({"loop": asdict(cfg.loop)} if cfg.loop is not None else {}),
            **({"mono": asdict(cfg.mono)} if cfg.mono is not None and cfg.runtime.sensor == "mono" else {})}


def _write_config(out_dir: Path, cfg) -> None:
    import yaml
    (out_dir / "config_used.yaml").write_text(yaml.safe_dump(_config_dict(cfg), sort_keys=False))
