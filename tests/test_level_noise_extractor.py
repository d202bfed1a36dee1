"""The per-cell extractor with each pyramid level's own noise floor (``LevelNoiseCellExtractor``,
docs/notes/s17-darkrows.md). On a generated dark-rows frame degraded as the grid's hazy noisy cell is
(haze 0.06 /m + the "high" noise sensor, ``canopy.degrade``): level 0 keeps ``CellExtractor``'s corners
to the pixel, the coarser levels' fallback thresholds follow their own (lower) noise, and the corners
that adds are found again in another noise draw of the same frame far more often than corners of pure
noise are (they are the scene's, not the noise's)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image, ray_length
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.features import OrbExtractor
from canopy.frontend.level_noise_extractor import LevelNoiseCellExtractor, level_thresholds
from canopy.frontend.noisy_features import NoiseGatedExtractor, tracking_extractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.track_health import image_noise_sigma
from canopy.synthetic import SequenceGenerator, resolve_params

FULL_WELL, READ_NOISE = NOISE_LEVELS["high"]


@pytest.fixture(scope="module")
def frames():
    """The clean left image of dark-rows frame 20 and three draws of it with haze 0.06 + the noisy sensor."""
    gen = SequenceGenerator(resolve_params("dark-rows", n_frames=40), 0)
    left, _, depth = gen.stereo(20)
    ray = ray_length(depth, gen.calibration)
    hazy = DegradeParams(mode="haze+noise", gain=1.0, full_well=FULL_WELL, read_noise=READ_NOISE, beta=0.06)
    return left, [degrade_image(left, hazy, ray, seed) for seed in (1, 2, 3)]


def params(**kw) -> TrackingParams:
    """configs/synthetic.yaml's noisy-extractor settings."""
    return replace(TrackingParams(), noisy_extractor_sigma=4.0, noisy_extractor_robust=True,
                   noisy_extractor_max_texture=2.0, cell_fallback_noise_factor=4.0, **kw).validate()


def extract(extractor, image):
    """As the tracker calls it: FAST threshold floor 3 sigma, the image's sigma handed on."""
    sigma = image_noise_sigma(image)
    return extractor.extract(image, max(20, int(round(3 * sigma))), None, 0, noise_sigma=sigma)


def found_again(a, b, rows) -> np.ndarray:
    """Per keypoint of ``a`` in ``rows``: a keypoint of ``b`` on the same octave within 1.5 level px."""
    d = np.linalg.norm(a.uv[rows][:, None, :] - b.uv[None, :, :], axis=2)
    same = a.octave[rows][:, None] == b.octave[None, :]
    return ((d <= 1.5 * 1.2 ** a.octave[rows][:, None]) & same).any(axis=1)


def test_level_thresholds_follow_the_level_noise_within_the_configured_bounds():
    # noise multiples of the level's sigma (3 x 2.1 -> 7 under the floor 20; 4 x 2.1 -> 9)
    assert level_thresholds(24, 22, 2.1, 20, 7, 3.0, 4.0) == (20, 9)
    # never below the configured thresholds
    assert level_thresholds(24, 22, 0.5, 20, 7, 3.0, 4.0) == (20, 7)
    # never above the full-resolution level's
    assert level_thresholds(24, 22, 9.0, 20, 7, 3.0, 4.0) == (24, 22)


def test_coarse_levels_get_their_own_floor_and_find_corners_of_the_scene(frames):
    _, noisy = frames
    p = replace(params(), extractor="cells")
    plain, per_level = CellExtractor(p, responses=False), LevelNoiseCellExtractor(p, responses=False)
    a0, a1 = extract(plain, noisy[0]), extract(per_level, noisy[0])
    # level 0 is CellExtractor's, to the pixel and the bit
    m0, m1 = a0.octave == 0, a1.octave == 0
    assert np.array_equal(a0.uv[m0], a1.uv[m1]) and np.array_equal(a0.descriptors[m0], a1.descriptors[m1])
    # the fallback threshold falls with the levels' noise (level 0: 4 x 5.3 sigma = 22 grey levels)
    lows = [low for _, low in per_level.last_level_thresholds]
    assert lows[0] == plain.last_stats["fast_low"] >= 20
    assert all(b <= a for a, b in zip(lows, lows[1:])) and lows[2] <= lows[0] // 2 + 1
    # more corners on the coarser levels
    assert (a1.octave > 0).sum() >= (a0.octave > 0).sum() + 60
    # the added corners are the scene's: found again in a second noise draw 25-35 % of the time (pure noise
    # corners: 2 %; the corners both extractors find: ~66 %)
    b1 = extract(per_level, noisy[1])
    added = ~found_again(a1, a0, np.ones(len(a1.uv), bool))
    assert added.sum() >= 60
    rng = np.random.default_rng(0)
    flat = [np.clip(100 + rng.normal(0, 6, noisy[0].shape), 0, 255).astype(np.uint8) for _ in range(2)]
    n1, n2 = extract(per_level, flat[0]), extract(per_level, flat[1])
    noise_repeat = found_again(n1, n2, np.ones(len(n1.uv), bool)).mean()
    added_repeat = found_again(a1, b1, added).mean()
    assert noise_repeat < 0.08 and added_repeat > 0.18


def test_switch_reaches_the_gated_extractor_and_leaves_clean_frames_to_cv2_orb(frames):
    clean, noisy = frames
    gate = tracking_extractor(params(noisy_extractor_level_noise=True), responses=False)
    assert isinstance(gate, NoiseGatedExtractor) and isinstance(gate.cells, LevelNoiseCellExtractor)
    assert not isinstance(tracking_extractor(params(), responses=False).cells, LevelNoiseCellExtractor)
    # a clean preset frame (robust sigma < 4) gets cv2.ORB's features as before
    f = extract(gate, clean)
    assert gate.last_used == "opencv"
    g = extract(OrbExtractor(params()), clean)
    assert np.array_equal(f.uv, g.uv) and np.array_equal(f.descriptors, g.descriptors)
    # the hazy noisy one the per-level extraction
    extract(gate, noisy[0])
    assert gate.last_used == "cells" and len(gate.cells.last_level_thresholds) == params().n_levels


def hazy_noisy_day_loop_frame() -> np.ndarray:
    """Generated day-loop frame 20 with haze 0.06 + the noisy sensor: a full-light orchard whose texture
    stands above the noise at full resolution (texture excess ~1.4 grey levels against dark-rows' ~0.4)."""
    gen = SequenceGenerator(resolve_params("day-loop", n_frames=40), 0)
    left, _, depth = gen.stereo(20)
    hazy = DegradeParams(mode="haze+noise", gain=1.0, full_well=FULL_WELL, read_noise=READ_NOISE, beta=0.06)
    return degrade_image(left, hazy, ray_length(depth, gen.calibration), 1)


def test_texture_gate_gives_the_level_floors_only_to_images_whose_texture_is_under_the_noise(frames):
    _, noisy = frames
    gated = tracking_extractor(params(noisy_extractor_level_noise=True, noisy_extractor_level_noise_max_texture=0.8),
                               responses=False)
    # the dark-rows hazy frame: texture excess under 0.8 -> each level's own floor, s17's corners to the pixel
    f = extract(gated, noisy[0])
    assert gated.last_used == "level_cells" and gated.last_texture < 0.8
    g = extract(tracking_extractor(params(noisy_extractor_level_noise=True), responses=False), noisy[0])
    assert np.array_equal(f.uv, g.uv) and np.array_equal(f.descriptors, g.descriptors)
    # the textured day-loop hazy frame: per-cell extraction with one floor, as without the switch
    day = hazy_noisy_day_loop_frame()
    f = extract(gated, day)
    assert gated.last_used == "cells" and gated.last_texture >= 0.8
    g = extract(tracking_extractor(params(), responses=False), day)
    assert np.array_equal(f.uv, g.uv) and np.array_equal(f.descriptors, g.descriptors)
    h = extract(tracking_extractor(params(noisy_extractor_level_noise=True), responses=False), day)
    assert not np.array_equal(h.uv, f.uv)  # the ungated switch would have changed this frame


def test_texture_gate_needs_the_level_noise_switch():
    with pytest.raises(Exception, match="noisy_extractor_level_noise_max_texture"):
        params(noisy_extractor_level_noise_max_texture=0.8)
    with pytest.raises(Exception, match="noisy_extractor_level_noise_max_texture"):
        params(noisy_extractor_level_noise=True, noisy_extractor_level_noise_max_texture=-1.0)
