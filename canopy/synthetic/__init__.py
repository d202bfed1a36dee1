"""Generated orchard stereo sequences with exact ground truth.

    from canopy.synthetic import generate_sequence, PRESETS
    path = generate_sequence("dusk-loop", Path("data/synthetic/dusk-loop"), seed=0)
    src = open_source("euroc", path)          # read by the ordinary EuRoC source

Modules: ``scene`` (primitives, procedural textures), ``renderer`` (vectorised
ray casting, z-buffer, exact depth), ``trajectories`` (row loop with U-turns
and revisit), ``conditions`` (light, shade, haze, sensor noise), ``presets``
(typed parameters, rigs, named presets), ``writer`` (EuRoC ASL output, cache).
"""
from __future__ import annotations

from .presets import PRESETS, RIGS, SyntheticParams, resolve_params
from .writer import SequenceGenerator, generate_sequence

__all__ = ["generate_sequence", "PRESETS", "RIGS", "SyntheticParams", "SequenceGenerator", "resolve_params"]
