"""Camera trajectories through the orchard: a racetrack around one row.

The path (world z up) drives lane 0 along +x, makes a U-turn around the end
of the row between lanes 0 and 1 into lane 1, drives back along -x, turns
into lane 0 again and continues past the start: a loop with a revisit. The
path is periodic in arc length, so any length works (several laps for long
sequences). Speed is smooth (ramp from standstill, slow swell, slower in the
turns); small vibrations (roll, pitch, yaw, bounce, sway) ride on top. All
deterministic from the seed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import OrchardScene

T0_NS = 1_600_000_000_000_000_000  # first stamp (ns); any fixed value works
SUBSTEPS = 20                       # speed integration steps per frame
# Camera axes at heading 0: x_cam = -y_world (right), y_cam = -z_world (down), z_cam = +x_world.
R_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class PathSpec:
    xa: float      # x of the lane-1 -> lane-0 turn centre
    xb: float      # x of the lane-0 -> lane-1 turn centre
    y0: float      # lane 0
    y1: float      # lane 1

    @property
    def radius(self) -> float:
        return 0.5 * (self.y1 - self.y0)

    @property
    def straight(self) -> float:
        return self.xb - self.xa

    @property
    def perimeter(self) -> float:
        return 2.0 * self.straight + 2.0 * np.pi * self.radius


def path_for(scene: OrchardScene, turn_margin: float = 4.2) -> PathSpec:
    """Racetrack around orchard row 1; turn centres clear the end posts and crowns."""
    L = scene.layout.row_length
    return PathSpec(xa=-turn_margin, xb=L + turn_margin, y0=scene.lane_y(0), y1=scene.lane_y(1))


def path_point(spec: PathSpec, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, heading, in_turn) at arc lengths ``s`` (periodic; s = 0 at (xa, y0))."""
    s = np.mod(np.asarray(s, dtype=np.float64), spec.perimeter)
    Ls, Rt = spec.straight, spec.radius
    arc = np.pi * Rt
    yc = 0.5 * (spec.y0 + spec.y1)
    x = np.empty_like(s)
    y = np.empty_like(s)
    psi = np.empty_like(s)
    turn = np.zeros_like(s, dtype=bool)
    a = s < Ls                                  # lane 0, +x
    x[a], y[a], psi[a] = spec.xa + s[a], spec.y0, 0.0
    b = (s >= Ls) & (s < Ls + arc)              # left U-turn around (xb, yc)
    th = -np.pi / 2 + (s[b] - Ls) / Rt
    x[b], y[b], psi[b], turn[b] = spec.xb + Rt * np.cos(th), yc + Rt * np.sin(th), th + np.pi / 2, True
    c = (s >= Ls + arc) & (s < 2 * Ls + arc)    # lane 1, -x
    x[c], y[c], psi[c] = spec.xb - (s[c] - Ls - arc), spec.y1, np.pi
    d = s >= 2 * Ls + arc                       # left U-turn around (xa, yc)
    th = np.pi / 2 + (s[d] - 2 * Ls - arc) / Rt
    x[d], y[d], psi[d], turn[d] = spec.xa + Rt * np.cos(th), yc + Rt * np.sin(th), th + np.pi / 2, True
    return x, y, psi, turn


def _rot(axis: int, a: np.ndarray) -> np.ndarray:
    """Rotations (N, 3, 3) about a coordinate axis by angles ``a``."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


def _smooth_wobble(rng: np.random.Generator, t: np.ndarray, amplitude: float, freqs: tuple[float, ...]) -> np.ndarray:
    """Sum of sinusoids with random phases and weights: smooth, bounded by ``amplitude``."""
    w = rng.uniform(0.5, 1.0, len(freqs))
    w /= w.sum()
    ph = rng.uniform(0, 2 * np.pi, len(freqs))
    return amplitude * sum(wk * np.sin(2 * np.pi * f * t + p) for wk, f, p in zip(w, freqs, ph))


@dataclass
class CameraTrack:
    """Frame stamps (int64 ns and float s) and poses ``T_world_cam`` (N, 4, 4), plus arc length."""

    stamps_ns: np.ndarray
    stamps: np.ndarray
    poses: np.ndarray
    arc_length: np.ndarray


def frames_for_length(length_m: float, speed: float, rate_hz: float, ramp_s: float = 2.0) -> int:
    """Frames needed to drive ``length_m`` at ``speed`` (cruise) including the start ramp."""
    return int(np.ceil((length_m / speed + ramp_s / 2.0) * rate_hz)) + 1


def make_track(scene: OrchardScene, n_frames: int, rate_hz: float, *, speed: float, seed: int,
               start_x: float = -2.5, cam_height: float = 1.0, tilt_deg: float = 6.0,
               vibration: float = 1.0, ramp_s: float = 2.0, turn_slowdown: float = 0.4,
               start_offset: float = 0.0) -> CameraTrack:
    """Sample ``n_frames`` poses at ``rate_hz`` along the racetrack of ``scene``."""
    spec = path_for(scene)
    rng = np.random.default_rng([seed, 0x7A])
    dt_ns = int(round(1e9 / rate_hz))
    stamps_ns = T0_NS + dt_ns * np.arange(n_frames, dtype=np.int64)
    t = np.arange(n_frames) * (dt_ns * 1e-9)

    # Integrate the speed profile finely; the speed depends on s (slower in turns).
    swell_f, swell_p = 1.0 / rng.uniform(6.0, 10.0), rng.uniform(0, 2 * np.pi)
    h = dt_ns * 1e-9 / SUBSTEPS
    s_frames = np.empty(n_frames)
    s = start_x - spec.xa + start_offset
    arc = np.pi * spec.radius
    turn_factor = 1.0
    for k in range(n_frames):
        s_frames[k] = s
        for j in range(SUBSTEPS):
            tt = t[k] + j * h
            ramp = 0.5 - 0.5 * np.cos(np.pi * min(tt / ramp_s, 1.0)) if ramp_s > 0 else 1.0
            sm = s % spec.perimeter
            in_turn = not (sm < spec.straight or spec.straight + arc <= sm < 2 * spec.straight + arc)
            # First-order lag towards the turn speed so the speed stays smooth.
            target = 1.0 - turn_slowdown if in_turn else 1.0
            turn_factor += (target - turn_factor) * min(h / 0.8, 1.0)
            v = speed * ramp * turn_factor * (1.0 + 0.06 * np.sin(2 * np.pi * swell_f * tt + swell_p))
            s += v * h
    x, y, psi, _ = path_point(spec, s_frames)

    vib = float(vibration)
    roll = _smooth_wobble(rng, t, np.deg2rad(0.6) * vib, (0.7, 2.3, 5.9))
    pitch = _smooth_wobble(rng, t, np.deg2rad(0.5) * vib, (0.5, 1.9, 6.7))
    yaw = _smooth_wobble(rng, t, np.deg2rad(0.8) * vib, (0.2, 0.9, 3.1))
    bounce = _smooth_wobble(rng, t, 0.012 * vib, (1.1, 3.7, 8.3))
    sway = _smooth_wobble(rng, t, 0.05 * vib, (0.05, 0.13))

    # Sway moves sideways (perpendicular to the heading).
    x = x - np.sin(psi) * sway
    y = y + np.cos(psi) * sway
    R = _rot(2, psi) @ R_BASE @ _rot(0, np.full(n_frames, -np.deg2rad(tilt_deg)))
    R = R @ _rot(2, roll) @ _rot(0, pitch) @ _rot(1, yaw)
    T = np.tile(np.eye(4), (n_frames, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = np.stack([x, y, cam_height + bounce], axis=1)
    stamps = (stamps_ns // 1_000_000_000).astype(np.float64) + (stamps_ns % 1_000_000_000) * 1e-9
    return CameraTrack(stamps_ns=stamps_ns, stamps=stamps, poses=T, arc_length=s_frames - s_frames[0])
