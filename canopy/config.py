"""One run's configuration: a YAML file per dataset, one typed section per actor.

``configs/<dataset>.yaml`` holds sections ``runtime``, ``enhancement``,
``tracking`` and ``mapping``; each becomes the frozen parameter dataclass of
the module that uses it (unknown keys are errors that name the file).
Command-line flags override single values after loading.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from shared.errors import ConfigError
from shared.params import load_yaml, params_from_mapping

REPO_ROOT = Path(__file__).resolve().parents[1]
CONFIG_DIR = REPO_ROOT / "configs"
CLOCK_MODES = ("lockstep", "realtime")
MIN_RING_SLOTS, MAX_RING_SLOTS = 2, 256
# Actors send a heartbeat every second (actors.runtime.STATS_PERIOD_S); a timeout shorter than
# two periods would call a healthy actor hung on one late message.
MIN_HEARTBEAT_TIMEOUT_S = 2.0
SENSORS = ("stereo", "mono")
# glibc refuses an M_MMAP_THRESHOLD above HEAP_MAX_SIZE / 2 (32 MB on 64-bit)
MAX_MALLOC_KEEP_MB = 32
MAX_MAP_UPDATE_LAG = 4  # tracking further ahead of its map than this only loses accuracy


@dataclass(frozen=True)
class RuntimeParams:
    clock: str = "lockstep"          # lockstep: deterministic; realtime: dataset rate, drops counted
    ring_slots: int = 8              # shared-memory slots per ring
    heartbeat_timeout_s: float = 5.0
    ready_timeout_s: float = 90.0    # actors import OpenCV and GTSAM on start
    grace_s: float = 1.0             # how long actors get to stop before being killed
    realtime_speed: float = 1.0      # 2.0 plays the dataset twice as fast
    max_lag_frames: float = 2.0      # realtime: a frame this many periods old is skipped if a newer one waits
    lockstep_wait_s: float = 60.0    # longest wait for a map update in lockstep
    # lockstep pipelining (canopy.pipeline.MapUpdateSchedule): the local-map update answering the
    # keyframe made at frame i is applied before frame i + 1 + lag is tracked, so tracking of the
    # next `lag` frames overlaps that keyframe's local BA (ORB-SLAM runs them concurrently); the
    # point of application is fixed, so runs stay repeatable. 0: wait for every update at once.
    map_update_lag_frames: int = 1
    # lockstep: frames the source may read (and enhancement process) ahead of tracking
    lockstep_prefetch_frames: int = 2
    # lockstep: tracking extracts a frame's features (ORB, stereo matches: no map needed) before it
    # waits for the map updates due at that frame, so the extraction overlaps local mapping's BA;
    # the same trajectory bit for bit (docs/notes/s16-fps.md)
    lockstep_extract_ahead: bool = True
    map_snapshot_period_s: float = 0.5
    # niceness of the source and enhancement actors (cheap feeders that read ahead in lockstep): on
    # two cores a feeder waking up should not take the core from tracking or local mapping; local
    # mapping stays at 0 (docs/notes/s6-speed.md), loop closing has its own (loop.niceness).
    # 15 rather than 5 (s9, benchmarks/bench_pipelining.py, 4 interleaved reps, quiet): tracking p50
    # EuRoC 37.4 -> 32.1 ms, KITTI 80.1 -> 76.4 ms, same trajectories; the feeders read two frames
    # ahead, so a later wake-up costs nothing in lockstep
    feeder_niceness: int = 15
    # niceness of local mapping (0: as tracking). configs/euroc.yaml: 5, where its per-frame BA cost made
    # tracking wait for a core; lockstep results do not depend on it (map updates land at fixed frames)
    mapping_niceness: int = 0
    # glibc's malloc in every actor process (actors.runtime.keep_freed_memory): freed blocks up to this
    # many MB stay in the process instead of going back to the kernel (M_MMAP_THRESHOLD, and
    # M_TRIM_THRESHOLD at 4x), so the per-frame temporaries of numpy/OpenCV do not page-fault in again
    # every frame (~2.5 us a fault, hundreds a frame on EuRoC: docs/notes/s19-mapsearch.md). 0: glibc's
    # own dynamic thresholds. 32 (s19, quiet interleaved A/B, 4 + 4 bench_peers runs): tracking-thread CPU
    # per KITTI frame 28.3 -> 25.3 ms (1.30 -> 1.21x ORB-SLAM3's in the same runs), EuRoC 15.9 -> 15.1; run-queue
    # wait 10.7 -> 9.9 / 4.8 -> 4.1 ms; minor faults of a launch 213 k -> 117 k; trajectories byte-equal.
    # Costs at most ~4 x 32 MB of freed heap kept per actor process.
    malloc_keep_mb: int = 32
    seed: int = 0
    sensor: str = "stereo"           # stereo | mono (the left image only; canopy.mono)

    def validate(self) -> None:
        if self.sensor not in SENSORS:
            raise ConfigError("runtime.sensor", f"must be one of {SENSORS}, got {self.sensor!r}")
        if self.clock not in CLOCK_MODES:
            raise ConfigError("runtime.clock", f"must be one of {CLOCK_MODES}, got {self.clock!r}")
        if not MIN_RING_SLOTS <= self.ring_slots <= MAX_RING_SLOTS:
            raise ConfigError("runtime.ring_slots", f"must be {MIN_RING_SLOTS}..{MAX_RING_SLOTS}, got {self.ring_slots}")
        # `not x > 0` also rejects NaN.
        for name in ("max_lag_frames", "realtime_speed", "ready_timeout_s", "lockstep_wait_s",
                     "map_snapshot_period_s"):
            value = getattr(self, name)
            if not value > 0 or value == float("inf"):
                raise ConfigError(f"runtime.{name}", f"must be a finite number > 0, got {value}")
        if not 0 <= self.map_update_lag_frames <= MAX_MAP_UPDATE_LAG:
            raise ConfigError("runtime.map_update_lag_frames",
                              f"must be 0..{MAX_MAP_UPDATE_LAG}, got {self.map_update_lag_frames}")
        # the source may write frame i + prefetch while tracking reads frame i from the same ring
        if not 0 <= self.lockstep_prefetch_frames <= self.ring_slots - 2:
            raise ConfigError("runtime.lockstep_prefetch_frames",
                              f"must be 0..ring_slots - 2 ({self.ring_slots - 2}), got {self.lockstep_prefetch_frames}")
        if not MIN_HEARTBEAT_TIMEOUT_S <= self.heartbeat_timeout_s < float("inf"):
            raise ConfigError("runtime.heartbeat_timeout_s",
                              f"must be at least {MIN_HEARTBEAT_TIMEOUT_S:g} s (actors send a heartbeat every "
                              f"second), got {self.heartbeat_timeout_s}")
        if not 0 <= self.feeder_niceness <= 19:
            raise ConfigError("runtime.feeder_niceness", f"must be 0..19, got {self.feeder_niceness}")
        if not 0 <= self.mapping_niceness <= 19:
            raise ConfigError("runtime.mapping_niceness", f"must be 0..19, got {self.mapping_niceness}")
        if not 0 <= self.malloc_keep_mb <= MAX_MALLOC_KEEP_MB:
            raise ConfigError("runtime.malloc_keep_mb", f"must be 0..{MAX_MALLOC_KEEP_MB}, got {self.malloc_keep_mb}")
        if not 0 <= self.grace_s < float("inf"):
            raise ConfigError("runtime.grace_s", f"must be a finite number >= 0, got {self.grace_s}")


@dataclass(frozen=True)
class RunConfig:
    runtime: RuntimeParams
    enhancement: object
    tracking: object
    mapping: object
    source_file: str
    loop: object = None              # canopy.loop.LoopParams (section ``loop``; issue 10)
    mono: object = None              # canopy.mono.MonoParams (section ``mono``, used with sensor: mono)


def default_config_path(dataset: str) -> Path:
    return CONFIG_DIR / f"{dataset}.yaml"


def load_run_config(dataset: str, config_path: str | Path | None = None) -> RunConfig:
    from canopy.backend import MappingParams
    from canopy.enhance import EnhanceParams
    from canopy.frontend import TrackingParams
    from canopy.loop.params import LoopParams
    from canopy.mono.params import MonoParams

    path = Path(config_path) if config_path else default_config_path(dataset)
    raw = load_yaml(path)
    known = {"runtime", "enhancement", "tracking", "mapping", "loop", "mono"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(path, f"unknown section(s) {unknown}; expected {sorted(known)}")
    src = str(path)
    for name in known:
        section = raw.get(name)
        if section is not None and not isinstance(section, dict):
            raise ConfigError(path, f"section '{name}' must be a mapping of parameter: value, "
                                    f"got a {type(section).__name__}")
    return RunConfig(
        runtime=params_from_mapping(RuntimeParams, raw.get("runtime"), src),
        enhancement=params_from_mapping(EnhanceParams, raw.get("enhancement"), src),
        tracking=params_from_mapping(TrackingParams, raw.get("tracking"), src),
        mapping=params_from_mapping(MappingParams, raw.get("mapping"), src),
        source_file=src,
        loop=params_from_mapping(LoopParams, raw.get("loop"), src),
        mono=params_from_mapping(MonoParams, raw.get("mono"), src),
    )


def with_overrides(cfg: RunConfig, clock: str | None = None, enhance: str | None = None,
                   lines: bool | None = None, loop: bool | None = None,
                   sensor: str | None = None) -> RunConfig:
    if loop is not None and cfg.loop is not None:
        cfg = replace(cfg, loop=replace(cfg.loop, enabled=loop))
    runtime = cfg.runtime if clock is None else replace(cfg.runtime, clock=clock)
    if sensor is not None:
        runtime = replace(runtime, sensor=sensor)
    if lines is not None:  # points + lines needs both tracking and local BA to agree
        cfg = replace(cfg, tracking=replace(cfg.tracking, use_lines=lines),
                      mapping=replace(cfg.mapping, use_lines=lines))
    runtime.validate()
    if runtime.sensor == "mono" and getattr(cfg.tracking, "use_lines", False):
        raise ConfigError("--lines", "line segments are not tracked in monocular mode (sensor: mono)")
    enhancement = cfg.enhancement if enhance is None else replace(cfg.enhancement, method=enhance)
    validate = getattr(enhancement, "validate", None)
    if callable(validate):
        validate()
    return replace(cfg, runtime=runtime, enhancement=enhancement)


def parse_setting(text: str) -> tuple[str, str, object]:
    """``section.field=value`` -> (section, field, value); the value as JSON when it parses
    (numbers, booleans, lists), else the string. For benchmark variants and ``--set`` flags."""
    key, sep, raw = text.partition("=")
    section, dot, field = key.partition(".")
    if not sep or not dot or not section or not field:
        raise ConfigError(text, "expected section.field=value, e.g. tracking.n_features=2000")
    return section, field, parse_value(raw)


def parse_value(raw: str):
    """A setting's value: JSON when it parses, else the string itself."""
    import json
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        return raw


def parse_variant(text: str) -> tuple[str, list[tuple[str, str, object]]]:
    """``name:section.field=value,section.field=value`` -> (name, settings)."""
    name, _, sets = text.partition(":")
    return name, [parse_setting(item) for item in filter(None, sets.split(","))]


def with_settings(cfg: RunConfig, settings) -> RunConfig:
    """``cfg`` with ``(section, field, value)`` settings applied to its typed sections (each section
    re-validated); an unknown section or field is a ConfigError naming it."""
    for section, field, value in settings:
        params = getattr(cfg, section, None) if section != "source_file" else None
        if params is None or not hasattr(params, field):
            raise ConfigError(f"{section}.{field}", "no such setting")
        try:
            params = replace(params, **{field: value})
        except TypeError as exc:
            raise ConfigError(f"{section}.{field}", str(exc)) from None
        validate = getattr(params, "validate", None)
        if callable(validate):
            validate()
        cfg = replace(cfg, **{section: params})
    return cfg
