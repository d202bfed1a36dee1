"""Typed parameters of a generated sequence, camera rigs and the named presets."""
from __future__ import annotations

from dataclasses import dataclass

from shared.errors import ConfigError
from shared.types import StereoCalibration

# Rectified pinhole rigs. cx, cy sit at the exact image centre ((W - 1) / 2):
# OpenCV's stereoRectify (used by the EuRoC reader) then returns K unchanged,
# so the rectified calibration a reader sees equals the one rendered with.
RIGS: dict[str, dict] = {
    # EuRoC MAV VI-sensor-like: 752x480, fx ~ 435 after rectification, 11 cm, 20 Hz.
    "euroc": {"width": 752, "height": 480, "fx": 435.0, "baseline": 0.11, "rate_hz": 20.0},
    # KITTI odometry-like: 1241x376, fx 718.856 (sequences 00-02), 0.537 m, 10 Hz.
    "kitti": {"width": 1241, "height": 376, "fx": 718.856, "baseline": 0.537, "rate_hz": 10.0},
}


@dataclass(frozen=True)
class SyntheticParams:
    """Everything that determines a generated sequence (besides the seed).

    n_frames and length_m: 0 means "derive" (length: one lap around the row
    plus ``revisit_m`` past the start; frames: from length and speed).
    """

    camera: str = "euroc"
    n_frames: int = 0
    length_m: float = 0.0
    speed: float = 1.6                # cruise speed, m/s
    revisit_m: float = 10.0           # distance driven past the start after one lap
    start_offset_m: float = 0.0       # start this far along the loop (arc length) from the row entrance
    # Orchard layout.
    n_rows: int = 5
    row_spacing: float = 4.0
    row_length: float = 20.0
    tree_spacing: float = 1.6
    # Camera motion.
    cam_height: float = 1.0
    tilt_deg: float = 6.0             # camera pitched down
    vibration: float = 1.0            # scale of roll/pitch/yaw/bounce/sway
    # Conditions.
    light_start: float = 1.0
    light_end: float = 1.0
    light_ramp: tuple[float, float] = (0.15, 0.95)  # fractions of the sequence
    haze_beta: float = 0.0            # 1/m; visibility ~ 3 / beta
    airlight: float = 0.85
    shade_strength: float = 0.45
    gain: float = 1.0                 # analogue gain (amplifies noise with the signal)
    noise: bool = True
    full_well: float = 6000.0         # electrons at DN 255 (gain 1)
    read_noise_e: float = 8.0
    low_texture: tuple[tuple[float, float], ...] = ()  # world-x ranges with washed-out ground/crowns
    low_texture_contrast: float = 0.15
    max_range: float = 45.0           # primitives beyond this (m) are not rendered
    write_depth: bool = True

    def validate(self) -> None:
        def bad(field: str, problem: str) -> ConfigError:
            return ConfigError(f"synthetic.{field}", problem)

        if self.camera not in RIGS:
            raise bad("camera", f"unknown camera rig {self.camera!r}; expected one of {', '.join(RIGS)}")
        if self.n_frames < 0:
            raise bad("n_frames", f"must be >= 0 (0 = derive from the length), got {self.n_frames}")
        if self.length_m < 0:
            raise bad("length_m", f"sequence length must be >= 0 m (0 = one lap), got {self.length_m:g}")
        if self.speed <= 0:
            raise bad("speed", f"must be > 0 m/s, got {self.speed:g}")
        if self.revisit_m < 0:
            raise bad("revisit_m", f"must be >= 0 m, got {self.revisit_m:g}")
        if self.haze_beta < 0:
            raise bad("haze_beta", f"haze density must be >= 0 (1/m), got {self.haze_beta:g}")
        if self.n_rows < 3:
            raise bad("n_rows", f"the loop drives two lanes, so it needs >= 3 rows, got {self.n_rows}")
        if self.row_spacing < 3.0:
            raise bad("row_spacing", f"rows closer than 3 m leave no lane for the crowns, got {self.row_spacing:g}")
        if self.tree_spacing < 0.5 or self.row_length < 2 * self.tree_spacing:
            raise bad("row_length", "need tree_spacing >= 0.5 m and a row of at least two trees")
        if not 0.3 <= self.cam_height <= 3.0:
            raise bad("cam_height", f"must be within 0.3..3 m, got {self.cam_height:g}")
        for name in ("light_start", "light_end", "airlight", "shade_strength", "read_noise_e", "vibration"):
            if getattr(self, name) < 0:
                raise bad(name, f"must be >= 0, got {getattr(self, name):g}")
        if self.shade_strength > 1:
            raise bad("shade_strength", f"must be <= 1, got {self.shade_strength:g}")
        if not 0 <= self.light_ramp[0] <= self.light_ramp[1] <= 1:
            raise bad("light_ramp", f"needs 0 <= start <= end <= 1, got {self.light_ramp}")
        if self.gain <= 0 or self.full_well <= 0:
            raise bad("gain", "gain and full_well must be > 0")
        for x0, x1 in self.low_texture:
            if not x0 < x1:
                raise bad("low_texture", f"each range needs x0 < x1, got ({x0:g}, {x1:g})")
        if not 0 <= self.low_texture_contrast <= 1:
            raise bad("low_texture_contrast", f"must be within 0..1, got {self.low_texture_contrast:g}")
        if self.max_range <= 1:
            raise bad("max_range", f"must be > 1 m, got {self.max_range:g}")

    @property
    def rig(self) -> dict:
        return RIGS[self.camera]

    @property
    def calibration(self) -> StereoCalibration:
        r = self.rig
        return StereoCalibration(fx=r["fx"], fy=r["fx"], cx=(r["width"] - 1) / 2.0, cy=(r["height"] - 1) / 2.0,
                                 baseline=r["baseline"], width=r["width"], height=r["height"])

    @property
    def rate_hz(self) -> float:
        return float(self.rig["rate_hz"])


# Each preset is a set of overrides of SyntheticParams.
PRESETS: dict[str, dict] = {
    # Bright day, one lap around a row and 10 m past the start: loop closure, drift.
    "day-loop": {},
    # The same loop while the light fades from late afternoon to dusk.
    "dusk-loop": {"light_start": 0.85, "light_end": 0.1, "light_ramp": (0.1, 0.95)},
    # One straight pass along a row in haze (visibility ~ 25 m).
    "haze-row": {"haze_beta": 0.12, "light_start": 0.9, "light_end": 0.9, "revisit_m": 0.0,
                 "length_m": 26.0},
    # Night-time loop with gain pushed up: dark, noisy frames.
    "dark-rows": {"light_start": 0.06, "light_end": 0.06, "gain": 2.5, "shade_strength": 0.3},
}

PRESET_HELP = {
    "day-loop": "daylight, lap of one row + revisit",
    "dusk-loop": "light fades day -> dusk over the lap",
    "haze-row": "straight pass along a row in haze (beta 0.12/m)",
    "dark-rows": "night lap, 6 % light, gain 2.5",
}


def resolve_params(preset: str, n_frames: int | None = None, **overrides) -> SyntheticParams:
    """SyntheticParams of ``preset`` with ``overrides``; clear ConfigError on an unknown preset or key."""
    from shared.params import params_from_mapping

    if preset not in PRESETS:
        raise ConfigError(f"preset {preset!r}", f"unknown preset; expected one of {', '.join(PRESETS)}")
    mapping = {**PRESETS[preset], **overrides}
    if n_frames is not None:
        mapping["n_frames"] = n_frames
    return params_from_mapping(SyntheticParams, mapping, source=f"synthetic preset {preset!r}")
