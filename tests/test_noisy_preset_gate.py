"""The generated presets' extractor gate (issue 9, docs/notes/s12-presets.md): ``NoiseGatedExtractor``
judged by the robust noise sigma and the texture excess. A clean preset frame must get exactly
cv2.ORB's features (the clean presets stay bit-identical), a noisy textured one too (the noise-only
day-loop cell, where the per-cell extraction loses), a noisy flat one (haze, the hazy row) the
per-cell extraction. The frames are rendered by the generator and degraded by the grid's own sensor
model (``canopy.degrade``, the "high" noise level), as the grid's cells are."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image, ray_length
from canopy.enhance.noise import estimate_noise
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.features import OrbExtractor
from canopy.frontend.noisy_features import NoiseGatedCellFallback, NoiseGatedExtractor, tracking_extractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.track_health import image_noise_sigma
from canopy.synthetic import SequenceGenerator, resolve_params
from shared.errors import ConfigError

FULL_WELL, READ_NOISE = NOISE_LEVELS["high"]


def _frame(preset: str):
    gen = SequenceGenerator(resolve_params(preset, n_frames=40), 0)
    left, right, depth = gen.stereo(20)
    return left, right, ray_length(depth, gen.calibration)


@pytest.fixture(scope="module")
def frames():
    """Clean / noise-only / haze 0.06 + noise left images of one day-loop and one haze-row frame."""
    out = {}
    for preset in ("day-loop", "haze-row"):
        left, right, ray = _frame(preset)
        noise = DegradeParams(mode="noise", gain=1.0, full_well=FULL_WELL, read_noise=READ_NOISE)
        haze = replace(noise, mode="haze+noise", beta=0.06)
        out[preset] = dict(clean=left, clean_right=right, noise=degrade_image(left, noise, ray, 1),
                           haze=degrade_image(left, haze, ray, 1))
    return out


def params() -> TrackingParams:
    """configs/synthetic.yaml's gate."""
    return replace(TrackingParams(), noisy_extractor_sigma=4.0, noisy_extractor_robust=True,
                   noisy_extractor_max_texture=2.0, cell_fallback_noise_factor=4.0).validate()


def same(a, b) -> bool:
    return (np.array_equal(a.uv, b.uv) and np.array_equal(a.octave, b.octave)
            and np.array_equal(a.descriptors, b.descriptors))


def test_robust_sigma_and_texture_excess_separate_the_presets_images(frames):
    day, row = frames["day-loop"], frames["haze-row"]
    robust = lambda img: estimate_noise(img, rows_fraction=0.5)  # noqa: E731
    excess = lambda img: image_noise_sigma(img) - robust(img)     # noqa: E731
    # the mean sigma sees the clean orchard's texture: above the gate, where the robust one is below
    assert image_noise_sigma(day["clean"]) > 4.0 > robust(day["clean"])
    for img in (day["clean_right"], row["clean"], row["clean_right"]):
        assert robust(img) < 3.2
    for img in (day["noise"], day["haze"], row["noise"], row["haze"]):
        assert robust(img) > 4.8
    # noisy and textured (the noise-only day-loop) vs noisy and flat (haze, the hazy row)
    assert excess(day["noise"]) > 2.3
    for img in (day["haze"], row["noise"], row["haze"]):
        assert excess(img) < 1.9


def test_gate_keeps_cv2_orb_on_clean_and_textured_noisy_images_and_cells_on_flat_noisy_ones(frames):
    p = params()
    gate = tracking_extractor(p, responses=False)
    assert isinstance(gate, NoiseGatedExtractor)
    orb = OrbExtractor(p)
    cells = CellExtractor(replace(p, extractor="cells"), responses=False)
    day, row = frames["day-loop"], frames["haze-row"]
    for img in (day["clean"], day["clean_right"], row["clean"], row["clean_right"], day["noise"]):
        assert same(gate.extract(img), orb.extract(img)) and gate.last_used == "opencv"
    for img in (day["haze"], row["noise"], row["haze"]):
        got = gate.extract(img)
        assert gate.last_used == "cells" and same(got, cells.extract(img))
        assert not same(got, orb.extract(img))
        assert got.robust_noise_sigma == pytest.approx(estimate_noise(img, rows_fraction=0.5))
    # a frame the enhancement changed (fallback threshold given) keeps cv2.ORB
    assert same(gate.extract(row["noise"], 20, 7), orb.extract(row["noise"], 20, 7))
    assert gate.last_used == "opencv"
    # without the texture test the noisy textured day-loop image goes to the per-cell extractor too
    loose = NoiseGatedExtractor(replace(p, noisy_extractor_max_texture=0.0), responses=False)
    loose.extract(day["noise"])
    assert loose.last_used == "cells"


def test_enhanced_frames_follow_the_enhanced_cells_rule_when_it_is_on(frames):
    """enhanced_cells_min_corners > 0: a frame the enhancement changed goes through CellExtractor's
    EnhancedCellsRule (the per-cell extractor when AFE's threshold finds enough corners, else cv2.ORB);
    0 (the default) keeps cv2.ORB."""
    row = frames["haze-row"]["noise"]
    on = replace(params(), enhanced_cells_min_corners=10)
    gate = NoiseGatedExtractor(on, responses=False)
    cells = CellExtractor(replace(on, extractor="cells"), responses=False)
    orb = OrbExtractor(on)
    got = gate.extract(row, 20, 7)  # a textured image: threshold 20 finds corners -> per-cell extraction
    assert gate.last_used == "enhanced" and cells._enhanced_rule.fallback(row, 20, 7) is not None
    assert same(got, cells.extract(row, 20, 7)) and not same(got, orb.extract(row, 20, 7))
    flat = np.full_like(row, 128)
    flat[200:240, 300:340] = 140  # one low-contrast square: no corner at threshold 20 -> cv2.ORB
    assert same(gate.extract(flat, 20, 7), orb.extract(flat, 20, 7))
    off = NoiseGatedExtractor(params(), responses=False)
    assert same(off.extract(row, 20, 7), orb.extract(row, 20, 7)) and off.last_used == "opencv"


def test_bad_settings_and_input_are_refused():
    with pytest.raises(ConfigError, match="noisy_extractor_max_texture"):
        replace(TrackingParams(), noisy_extractor_max_texture=-1.0).validate()
    with pytest.raises(ConfigError, match="noisy_extractor_robust"):
        replace(TrackingParams(), noisy_extractor_sigma=4.0, noisy_extractor_max_texture=2.0).validate()
    gate = NoiseGatedExtractor(params(), responses=False)
    with pytest.raises(ValueError, match="image"):
        gate.extract(np.zeros((4, 4, 3), np.uint8))


def test_both_noise_gates_name_themselves_on_a_bad_image():
    colour = np.zeros((40, 60, 3), np.uint8)
    presets = NoiseGatedExtractor(TrackingParams(noisy_extractor_sigma=4.0, noisy_extractor_robust=True))
    with pytest.raises(ValueError, match="NoiseGatedExtractor.extract: image must be a non-empty 2-D uint8"):
        presets.extract(colour)
    kitti = NoiseGatedCellFallback(TrackingParams(extractor="cells", cell_fallback_noisy_sigma=2.5))
    with pytest.raises(ValueError, match=r"NoiseGatedCellFallback.extract: .* got shape \(40, 60, 3\)"):
        kitti.extract(colour)
