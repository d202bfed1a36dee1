"""The noise energy of a resampled SAD window (canopy.frontend.keypoint_uncertainty.sampled_noise_factors):
white noise of known sigma, sampled as row_gradient_energy samples it at each octave's spacing, carries
the energy and per-sample variance the function predicts, and the bound built on it is finite where
white-noise arithmetic over-counts the noise into an infinite one."""
import numpy as np

from canopy.frontend.keypoint_uncertainty import disparity_sigma, row_gradient_energy, sampled_noise_factors

SCALES = 1.2 ** np.arange(8)


def _keypoints(rng, k, integer):
    uv = np.stack([rng.uniform(60, 580, k), rng.uniform(60, 420, k)], axis=1)
    return np.round(uv) if integer else uv


def test_predicted_noise_energy_matches_sampled_white_noise_at_every_octave():
    rng = np.random.default_rng(3)
    sigma = 7.0
    noise = rng.normal(0.0, sigma, (480, 640)).astype(np.float32)
    for octave in range(4):
        uv = _keypoints(rng, 400, integer=octave == 0).astype(np.float32)
        spacing = np.full(len(uv), SCALES[octave])
        sxx, n = row_gradient_energy(noise, uv, spacing, 5)
        energy, per_sample = sampled_noise_factors(uv, spacing, 5)
        ratio = sxx.mean() / (energy.mean() * sigma**2)
        assert abs(ratio - 1.0) < 0.06, (octave, ratio)
        if octave == 0:  # on the pixel grid: white-noise arithmetic exactly
            assert np.allclose(energy, n / 2.0) and np.allclose(per_sample, 1.0)
        else:  # resampled: ~4/9 of it, which white-noise arithmetic misses
            assert 0.38 < energy.mean() / (n / 2.0) < 0.5
            assert 0.38 < per_sample.mean() < 0.5


def test_sampled_noise_gives_a_finite_bound_where_white_arithmetic_gives_none():
    """A weak texture at octave 2 whose window energy is ~1.5x the resampled noise's (0.65x white
    noise's n sigma^2 / 2): white-noise arithmetic removes more than the window holds (an infinite
    bound); the sampled model leaves the texture's part and gives a finite one."""
    rng = np.random.default_rng(5)
    sigma = 6.0
    xs = np.arange(640, dtype=np.float32)
    texture = 6.0 * np.sin(xs / 3.0)[None, :].repeat(480, axis=0)
    image = 128.0 + texture + rng.normal(0.0, sigma, (480, 640)).astype(np.float32)
    uv = _keypoints(rng, 300, integer=False).astype(np.float32)
    octave = np.full(len(uv), 2)
    white = disparity_sigma(image, uv, octave, SCALES, sigma, 5)
    sampled = disparity_sigma(image, uv, octave, SCALES, sigma, 5, sampled_noise=True)
    assert np.mean(np.isinf(white)) > 0.9
    assert np.mean(np.isfinite(sampled)) > 0.9
