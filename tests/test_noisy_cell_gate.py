"""KITTI's gate on the cells extractor's fallback factor (issue 9, docs/notes/s11-noise.md): the
4 sigma fallback only on images whose robust noise sigma (``estimate_noise``, the sub-pixel
refinement's estimator) is at least ``cell_fallback_noisy_sigma``; clean KITTI images must get
exactly the ungated extractor's features (clean KITTI 06 stays bit-identical)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canopy.enhance.noise import estimate_noise
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.noisy_features import NoiseGatedCellFallback, tracking_extractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.track_health import image_noise_sigma
from canopy.sources import open_source
from shared.errors import ConfigError


@pytest.fixture(scope="module")
def kitti_pair():
    f = open_source("kitti", max_frames=6).frame(5)
    return f.left, f.right


def with_noise(image: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(image + rng.normal(0.0, sigma, image.shape), 0, 255).astype(np.uint8)


def params() -> TrackingParams:
    return replace(TrackingParams(), extractor="cells", cell_fallback_noisy_sigma=2.5,
                   cell_fallback_noise_factor_noisy=4.0, cell_fallback_noisy_min_texture=2.15)


def hazy(image: np.ndarray, t: float = 0.35, airlight: float = 220.0) -> np.ndarray:
    """Koschmieder's model with one transmission for the whole image: the contrast falls by t."""
    return np.clip(image * t + airlight * (1 - t), 0, 255).astype(np.uint8)


def same(a, b) -> bool:
    return (np.array_equal(a.uv, b.uv) and np.array_equal(a.octave, b.octave)
            and np.array_equal(a.descriptors, b.descriptors))


def test_robust_sigma_separates_clean_kitti_from_the_low_noise_sensor_where_the_mean_one_does_not(kitti_pair):
    left, right = kitti_pair
    noisy = with_noise(left, 3.0, 0)
    # the fallback floor's estimator sees KITTI's texture: clean ~5-6, above the noisy image's robust sigma
    assert image_noise_sigma(left) > 4.0
    assert estimate_noise(left, rows_fraction=0.5) < 2.3 and estimate_noise(right, rows_fraction=0.5) < 2.3
    assert estimate_noise(noisy, rows_fraction=0.5) > 2.7


def test_gate_gives_the_ungated_features_on_clean_images_and_the_4_sigma_floor_on_noisy_ones(kitti_pair):
    left, right = kitti_pair
    p = params()
    gate = tracking_extractor(p, responses=False)
    assert isinstance(gate, NoiseGatedCellFallback)
    plain = CellExtractor(p, responses=False)
    four = CellExtractor(replace(p, cell_fallback_noise_factor=4.0), responses=False)
    for img in (left, right):
        assert same(gate.extract(img), plain.extract(img)) and gate.last_used == "clean"
    noisy = with_noise(left, 3.0, 1)
    got = gate.extract(noisy)
    assert gate.last_used == "noisy" and same(got, four.extract(noisy))
    assert not same(got, plain.extract(noisy))        # the gate changes something on a noisy image
    # the same noise on a hazy copy: the texture no longer stands above the noise, no 4 sigma floor
    foggy = with_noise(hazy(left), 3.0, 1)
    assert estimate_noise(foggy, rows_fraction=0.5) >= 2.5
    assert same(gate.extract(foggy), plain.extract(foggy)) and gate.last_used == "clean"
    assert four.last_stats["fast_low"] >= 4 * image_noise_sigma(noisy)
    # a frame the enhancement changed (fallback threshold given) keeps the ungated path (cv2.ORB)
    assert same(gate.extract(noisy, 20, 7), plain.extract(noisy, 20, 7)) and gate.last_used == "clean"


def test_gate_off_is_the_plain_extractor_and_bad_input_is_refused(kitti_pair):
    assert isinstance(tracking_extractor(replace(params(), cell_fallback_noisy_sigma=0.0)), CellExtractor)
    with pytest.raises(ConfigError, match="cell_fallback_noisy_sigma"):
        replace(params(), cell_fallback_noisy_sigma=-1.0)
    with pytest.raises(ConfigError, match="cell_fallback_noise_factor_noisy"):
        replace(params(), cell_fallback_noise_factor_noisy=-1.0)
    with pytest.raises(ConfigError, match="cell_fallback_noisy_min_texture"):
        replace(params(), cell_fallback_noisy_min_texture=-1.0)
    with pytest.raises(ValueError, match="cell_fallback_noisy_sigma"):
        NoiseGatedCellFallback(replace(params(), cell_fallback_noisy_sigma=0.0))
    with pytest.raises(ValueError, match="image"):
        NoiseGatedCellFallback(params()).extract(np.zeros((4, 4, 3), np.uint8))


def test_gate_hands_its_robust_sigma_to_the_stereo_refinement(kitti_pair):
    """The gate's robust sigma is the refinement's figure of the same image: the stereo step reuses
    it (Features.robust_noise_sigma) and gets the very pair it would have measured itself."""
    from canopy.frontend.noisy_features import refinement_pair
    left, right = (with_noise(im, 6.0, seed) for im, seed in zip(kitti_pair, (3, 4)))
    p = replace(params(), subpixel_denoise_sigma=4.0, subpixel_denoise_blur=2.0)
    features = NoiseGatedCellFallback(p, responses=False).extract(left)
    assert features.robust_noise_sigma == estimate_noise(left, rows_fraction=0.5)
    assert features.subset(np.arange(3)).robust_noise_sigma == features.robust_noise_sigma
    measured = refinement_pair(left, right, p)
    reused = refinement_pair(left, right, p, features.robust_noise_sigma)
    assert reused[2] == measured[2] >= 4.0  # noisy: the blurred pair
    assert np.array_equal(reused[0], measured[0]) and np.array_equal(reused[1], measured[1])
    assert not np.array_equal(reused[0], left)
    # frames the enhancement changed are not measured by the gate: the refinement measures them
    assert NoiseGatedCellFallback(p, responses=False).extract(left, 20, 7).robust_noise_sigma is None
