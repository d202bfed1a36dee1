"""Imaging conditions applied to a noise-free render: shade, light, haze, sensor.

Order (physically: scene radiance -> atmosphere -> sensor):
1. low-texture stretches: ground and crowns inside given world-x ranges lose
   most of their contrast (bare, wet soil; a blurred hedge);
2. canopy shade: ground, trunks and posts near a row are darkened, with
   sun flecks from a low-frequency noise field in world coordinates;
3. light level ``L`` (day 1.0 → dusk → dark), scaling everything incl. sky;
4. haze (Koschmieder): ``I = J·t + A·L·(1 − t)``, ``t = exp(−β·r)`` with ``r``
   the exact range along the ray (depth × ray length; the sky has t = 0);
5. sensor: photo-electrons ``e = I·full_well``, shot noise (Poisson, normal
   approximation √e) plus read noise, analogue gain, 8-bit quantisation.
"""
from __future__ import annotations

import numpy as np

from shared.types import StereoCalibration

from .renderer import CANOPY, GROUND, SKY, RenderOutput, _sample, fast_mod
from .scene import OrchardScene, _periodic_noise

FLECK_TEXEL = 0.15  # metres per texel of the sun-fleck field


def smoothstep(x: np.ndarray | float) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def light_schedule(n_frames: int, start: float, end: float, ramp: tuple[float, float]) -> np.ndarray:
    """Light level per frame: ``start`` until fraction ramp[0] of the sequence, smooth to ``end`` at ramp[1]."""
    f = np.arange(n_frames) / max(n_frames - 1, 1)
    r0, r1 = ramp
    w = smoothstep((f - r0) / max(r1 - r0, 1e-9))
    return start + (end - start) * w


class Conditions:
    """Per-sequence state for ``apply`` (ray lengths, sun-fleck field)."""

    def __init__(self, calibration: StereoCalibration, scene: OrchardScene, seed: int):
        c = calibration
        u = (np.arange(c.width) - c.cx) / c.fx
        v = (np.arange(c.height) - c.cy) / c.fy
        self.ray_length = np.sqrt(1.0 + u[None, :] ** 2 + v[:, None] ** 2).astype(np.float32)
        rng = np.random.default_rng([seed, 0xF1EC])
        self.fleck = np.tanh(1.5 * _periodic_noise(rng, (256, 256), (2.0, 2.0))).astype(np.float32)
        self.scene = scene

    def apply(self, out: RenderOutput, rng: np.random.Generator, *, light: float, haze_beta: float,
              airlight: float, shade_strength: float, gain: float, noise: bool, full_well: float,
              read_noise_e: float, low_texture_contrast: float) -> np.ndarray:
        """uint8 image of ``out`` under the given conditions (``rng`` draws the sensor noise)."""
        J = out.radiance
        lab = out.label
        wx, wy = out.world_x, out.world_y
        zones = self.scene.low_texture_x
        if zones:
            inside = np.zeros(J.shape, bool)
            with np.errstate(invalid="ignore"):
                for x0, x1 in zones:
                    inside |= (wx >= x0) & (wx <= x1)
            inside &= (lab == GROUND) | (lab == CANOPY)
            k = np.float32(low_texture_contrast)
            J = np.where(inside, np.float32(0.3) + (J - np.float32(0.3)) * k, J)
        if shade_strength > 0:
            rs = np.float32(self.scene.layout.row_spacing)
            # Rows sit at multiples of the row spacing: distance to the nearest row line.
            row_off = np.abs(fast_mod(wy + rs / 2, rs) - rs / 2)
            cover = smoothstep((np.float32(1.9) - row_off) / np.float32(0.9))
            # Sky pixels carry NaN world coordinates; remap maps them to the border (ignored below).
            fleck = _sample(self.fleck, wx * np.float32(1.0 / FLECK_TEXEL), wy * np.float32(1.0 / FLECK_TEXEL))
            shade = np.float32(1.0) - np.float32(shade_strength) * cover * (np.float32(0.7) + np.float32(0.3) * fleck)
            shaded = (lab != SKY) & (lab != CANOPY)
            J = np.where(shaded, J * shade, J)
        I = J * np.float32(light)
        if haze_beta > 0:
            with np.errstate(invalid="ignore", over="ignore"):
                t = np.exp(-np.float32(haze_beta) * out.depth * self.ray_length)
            t = np.where(lab == SKY, np.float32(0.0), t)
            I = I * t + np.float32(airlight * light) * (np.float32(1.0) - t)
        if noise:
            e = np.maximum(I, 0) * np.float32(full_well)
            sigma = np.sqrt(e + np.float32(read_noise_e**2))
            e = e + sigma * rng.standard_normal(I.shape, dtype=np.float32)
            I = e / np.float32(full_well)
        dn = I * np.float32(255.0 * gain)
        return np.clip(np.rint(dn), 0, 255).astype(np.uint8)
