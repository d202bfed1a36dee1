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
SENSORS = ("stereo", "mono")


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
    map_snapshot_period_s: float = 0.5
    seed: int = 0
    sensor: str = "stereo"           # stereo | mono (the left image only; canopy.mono)

    def validate(self) -> None:
        if self.sensor not in SENSORS:
            raise ConfigError("runtime.sensor", f"must be one of {SENSORS}, got {self.sensor!r}")
        if self.clock not in CLOCK_MODES:
            raise ConfigError("runtime.clock", f"must be one of {CLOCK_MODES}, got {self.clock!r}")
        if self.ring_slots < 2:
            raise ConfigError("runtime.ring_slots", "needs at least 2 slots")
        if self.max_lag_frames <= 0:
            raise ConfigError("runtime.max_lag_frames", "must be > 0")
        if self.realtime_speed <= 0:
            raise ConfigError("runtime.realtime_speed", "must be > 0")


@dataclass(frozen=True)
class RunConfig:
    runtime: RuntimeParams
    enhancement: object
    tracking: object
    mapping: object
    source_file: str
    mono: object = None              # canopy.mono.MonoParams (section ``mono``, used with sensor: mono)


def default_config_path(dataset: str) -> Path:
    return CONFIG_DIR / f"{dataset}.yaml"


def load_run_config(dataset: str, config_path: str | Path | None = None) -> RunConfig:
    from canopy.backend import MappingParams
    from canopy.enhance import EnhanceParams
    from canopy.frontend import TrackingParams
    from canopy.mono.params import MonoParams

    path = Path(config_path) if config_path else default_config_path(dataset)
    raw = load_yaml(path)
    known = {"runtime", "enhancement", "tracking", "mapping", "mono"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(path, f"unknown section(s) {unknown}; expected {sorted(known)}")
    src = str(path)
    return RunConfig(
        runtime=params_from_mapping(RuntimeParams, raw.get("runtime"), src),
        enhancement=params_from_mapping(EnhanceParams, raw.get("enhancement"), src),
        tracking=params_from_mapping(TrackingParams, raw.get("tracking"), src),
        mapping=params_from_mapping(MappingParams, raw.get("mapping"), src),
        source_file=src,
        mono=params_from_mapping(MonoParams, raw.get("mono"), src),
    )


def with_overrides(cfg: RunConfig, clock: str | None = None, enhance: str | None = None,
                   lines: bool | None = None, sensor: str | None = None) -> RunConfig:
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
