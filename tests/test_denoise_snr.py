"""The denoiser's ε factor from the frame's texture SNR (canopy.enhance.snr, s15-snr): the measure follows
the texture-to-noise ratio of a generated frame and not the gain; the ramp between the two factors; the
same pixels as without the rule under the σ gate and at low SNR; one factor for both images of a pair;
bad values refused. Real images only from the project's ``data/``."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image
from canopy.enhance import EnhanceParams, make_enhancer, pair_arguments
from canopy.enhance.agcwd import agcwd_unsharp
from canopy.enhance.auto import apply_gamma, auto_treat
from canopy.enhance.noise import denoise
from canopy.enhance.pair import PairEnhancer
from canopy.enhance.snr import snr_eps_factor, texture_snr
from shared.errors import ConfigError

DATA = Path(__file__).resolve().parents[1] / "data"
KITTI_L = DATA / "kitti06_snippet" / "image_l" / "000010.png"
KITTI_R = DATA / "kitti06_snippet" / "image_r" / "000010.png"

RULE = dict(denoise_noisy_sigma=11.0, denoise_eps_factor_noisy=1.25, denoise_snr_low=3.0, denoise_snr_high=4.0)


def _texture(seed: int = 0, shape=(480, 752)) -> np.ndarray:
    """A smooth random texture (std 1, zero mean): white noise blurred at 3 px, the scale of ORB's
    coarse pyramid levels."""
    field = cv2.GaussianBlur(np.random.default_rng(seed).standard_normal(shape).astype(np.float32), (0, 0), 3.0)
    return (field - field.mean()) / field.std()


def _frame(texture_std: float, sigma: float, mean: float = 60.0, seed: int = 1) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(0.0, sigma, _texture().shape)
    return np.clip(np.rint(mean + texture_std * _texture() + noise), 0, 255).astype(np.uint8)


def test_texture_snr_follows_the_texture_over_the_noise_and_not_the_gain():
    sigma = 16.0
    # pure noise: only the spread of a 3×3 sample variance is left over its mean (χ²₈'s 90th percentile
    # over 9 minus 8/9: 0.60), far under the rule's 3
    assert texture_snr(_frame(0.0, sigma), sigma) == pytest.approx(13.36 / 9 - 8 / 9, abs=0.1)
    snrs = [texture_snr(_frame(t, sigma), sigma) for t in (4.0, 8.0, 16.0)]
    assert snrs[0] < snrs[1] < snrs[2]
    # against the noiseless texture's own top-decile window variance at ¼ scale over σ²/16
    for t, measured in zip((8.0, 16.0), snrs[1:]):
        # the noiseless frame's p90 window variance at ¼ scale, q, from texture_snr(., σ=1) = 16 q − 8/9
        q = (texture_snr(_frame(t, 0.0), 1.0) + 8.0 / 9.0) / 16.0
        truth = q / (sigma ** 2 / 16.0)
        assert measured == pytest.approx(truth, rel=0.3)
    # a gain lifts texture and noise alike: the ratio stays (the denoiser sees frames after AFE's gain)
    lo = _frame(4.0, 4.0, mean=20.0)
    hi = np.clip(np.rint(3.0 * lo.astype(np.float32)), 0, 255).astype(np.uint8)
    assert texture_snr(hi, 12.0) == pytest.approx(texture_snr(lo, 4.0), rel=0.1)


def test_factor_ramps_with_the_snr_over_the_sigma_gate():
    p = EnhanceParams(**RULE)
    sigma = 16.0
    textured, flat = _frame(24.0, sigma), _frame(2.0, sigma)
    assert texture_snr(textured, sigma) > 4.0 and texture_snr(flat, sigma) < 3.0
    assert snr_eps_factor(textured, sigma, p) == 1.25
    assert snr_eps_factor(flat, sigma, p) == 2.0
    mid = next(f for f in (_frame(t, sigma) for t in np.arange(6.0, 20.0, 0.5)) if 3.0 < texture_snr(f, sigma) < 4.0)
    assert 1.25 < snr_eps_factor(mid, sigma, p) < 2.0
    # under the σ gate (the clean presets' dark frames: σ ≤ 9.2) the factor stays 2 whatever the texture
    assert snr_eps_factor(textured, 10.9, p) == 2.0
    # SNR rule off: s14's σ-only rule (every frame over the gate gets the noisy factor)
    s14 = replace(p, denoise_snr_high=0.0)
    assert snr_eps_factor(flat, sigma, s14) == 1.25
    assert snr_eps_factor(flat, sigma, EnhanceParams()) == 2.0


def _dark(gain: float, noise: str = "high"):
    left, right = (cv2.imread(str(q), cv2.IMREAD_GRAYSCALE) for q in (KITTI_L, KITTI_R))
    assert left is not None and right is not None, "test data missing: data/kitti06_snippet"
    cell = DegradeParams(mode="dark", gain=gain, full_well=NOISE_LEVELS[noise][0], read_noise=NOISE_LEVELS[noise][1])
    return degrade_image(left, cell, rng=1), degrade_image(right, cell, rng=2)


def test_more_light_more_texture_above_the_noise_weaker_filter():
    """KITTI with the grid's noisy sensor: at 15 % light the street's texture stands above the noise, at
    2 % it does not; both are over the σ gate. The rule weakens the filter on the first only, and the
    second gets the pixels it gets without the rule."""
    p = EnhanceParams(method="auto", **RULE)
    base = EnhanceParams(method="auto")
    out15, dec15, sigma15, gamma15 = auto_treat(_dark(0.15)[0], p)
    lifted15 = apply_gamma(agcwd_unsharp(_dark(0.15)[0], p), gamma15)
    assert dec15 == "afe>dn" and sigma15 >= 11.0
    assert texture_snr(lifted15, sigma15) > 4.0
    assert np.array_equal(out15, denoise(lifted15, sigma15, p.denoise_radius, 1.25))
    dark2 = _dark(0.02)[0]
    out2, dec2, sigma2, gamma2 = auto_treat(dark2, p)
    assert dec2 == "afe>dn" and sigma2 >= 11.0
    assert texture_snr(apply_gamma(agcwd_unsharp(dark2, p), gamma2), sigma2) < 3.0
    assert np.array_equal(out2, auto_treat(dark2, base)[0])


def test_pair_enhancer_and_make_enhancer_give_both_images_the_left_factor():
    p = EnhanceParams(method="auto", **RULE)
    left, right = _dark(0.15)
    enhance = make_enhancer(p)
    le, info = enhance(left)
    re, rinfo = enhance(right, **pair_arguments(info))
    pl, pr, pinfo = PairEnhancer(p)(left, right)
    assert info["eps_factor"] == pinfo["eps_factor"] == rinfo["eps_factor"] == 1.25
    assert np.array_equal(le, pl) and np.array_equal(re, pr)
    lifted_r = apply_gamma(agcwd_unsharp(right, p), info["gamma"])
    assert np.array_equal(re, denoise(lifted_r, info["noise_sigma"], p.denoise_radius, 1.25))
    # a frame auto leaves alone reports no factor
    lit = cv2.imread(str(KITTI_L), cv2.IMREAD_GRAYSCALE)
    assert make_enhancer(p)(lit)[1]["eps_factor"] == 0.0


@pytest.mark.parametrize("bad", [{"denoise_snr_low": -1.0}, {"denoise_snr_high": -0.5},
                                 {"denoise_snr_low": 4.0, "denoise_snr_high": 3.0},
                                 {"denoise_snr_quantile": 1.0}, {"denoise_snr_downsample": 0},
                                 {"denoise_snr_high": float("nan")}])
def test_bad_snr_settings_are_refused_by_name(bad):
    with pytest.raises(ConfigError) as info:
        EnhanceParams(**bad)
    assert next(iter(bad)) in info.value.source or "denoise_snr_high" in info.value.source


def test_texture_snr_refuses_a_bad_sigma():
    with pytest.raises(ValueError, match="sigma"):
        texture_snr(_frame(4.0, 4.0), 0.0)
