"""The denoiser's ε factor on noisy dark frames (canopy.enhance.noisy_dark, s14-darkrows): the gate by the
σ the denoiser measures, bit-identical when off or under the gate, the same in ``auto_treat`` and
``PairEnhancer``; bad values refused. Real images only from the project's ``data/``."""
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
from canopy.enhance.noisy_dark import denoise_eps_factor
from canopy.enhance.pair import PairEnhancer
from shared.errors import ConfigError

DATA = Path(__file__).resolve().parents[1] / "data"
KITTI_L = DATA / "kitti06_snippet" / "image_l" / "000010.png"
KITTI_R = DATA / "kitti06_snippet" / "image_r" / "000010.png"


def _dark(noise: str, gain: float = 0.15):
    left, right = (cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in (KITTI_L, KITTI_R))
    assert left is not None and right is not None, "test data missing: data/kitti06_snippet"
    cell = DegradeParams(mode="dark", gain=gain, full_well=NOISE_LEVELS[noise][0], read_noise=NOISE_LEVELS[noise][1])
    return degrade_image(left, cell, rng=1), degrade_image(right, cell, rng=2)


def test_factor_follows_the_gate():
    off = EnhanceParams(denoise_eps_factor_noisy=1.0)
    on = replace(off, denoise_noisy_sigma=11.0)
    assert denoise_eps_factor(30.0, off) == 2.0                  # gate 0: off whatever the σ
    assert denoise_eps_factor(10.9, on) == 2.0
    assert denoise_eps_factor(11.0, on) == 1.0
    assert denoise_eps_factor(40.0, on) == 1.0


def test_noisy_dark_frame_gets_the_noisy_factor_and_quiet_ones_stay_bit_identical():
    base = EnhanceParams(method="auto")
    gated = replace(base, denoise_noisy_sigma=11.0, denoise_eps_factor_noisy=1.0)
    noisy, _ = _dark("high")
    quiet, _ = _dark("low")
    out_base, dec, sigma, gamma = auto_treat(noisy, base)
    out_gated, dec_g, sigma_g, gamma_g = auto_treat(noisy, gated)
    assert dec == dec_g == "afe>dn" and sigma == sigma_g and gamma == gamma_g
    assert sigma >= 11.0                                         # the high-noise sensor at 15 % light: over the gate
    # over the gate: the AFE + exposure-curve frame denoised with ε = σ² instead of (2σ)²
    lifted = apply_gamma(agcwd_unsharp(noisy, base), gamma)
    assert np.array_equal(out_gated, denoise(lifted, sigma, base.denoise_radius, 1.0))
    assert np.array_equal(out_base, denoise(lifted, sigma, base.denoise_radius, 2.0))
    # a weaker filter leaves more of the noise
    assert not np.array_equal(out_base, out_gated)
    assert float(np.std(cv2.Laplacian(out_gated, cv2.CV_32F))) > float(np.std(cv2.Laplacian(out_base, cv2.CV_32F)))
    # under the gate (low-noise sensor, σ ~5): the same pixels as without the rule
    q_base, _, s_quiet, _ = auto_treat(quiet, base)
    assert s_quiet < 11.0
    assert np.array_equal(q_base, auto_treat(quiet, gated)[0])


def test_pair_enhancer_and_make_enhancer_apply_the_same_factor_to_both_images():
    gated = EnhanceParams(method="auto", denoise_noisy_sigma=11.0, denoise_eps_factor_noisy=1.0)
    left, right = _dark("high")
    enhance = make_enhancer(gated)
    le, info = enhance(left)
    re, _ = enhance(right, **pair_arguments(info))
    pl, pr, pinfo = PairEnhancer(gated)(left, right)
    assert info["noise_sigma"] >= 11.0 and pinfo["noise_sigma"] == info["noise_sigma"]
    assert np.array_equal(le, pl) and np.array_equal(re, pr)
    # the right image is denoised with the left image's σ, hence with the same ε factor
    lifted_r = apply_gamma(agcwd_unsharp(right, gated), info["gamma"])
    assert np.array_equal(re, denoise(lifted_r, info["noise_sigma"], gated.denoise_radius, 1.0))


@pytest.mark.parametrize("bad", [{"denoise_noisy_sigma": -1.0}, {"denoise_eps_factor_noisy": 0.0},
                                 {"denoise_noisy_sigma": float("nan")}, {"denoise_eps_factor_noisy": True}])
def test_bad_values_are_refused_by_name(bad):
    with pytest.raises(ConfigError, match=next(iter(bad))):
        EnhanceParams(**bad)
