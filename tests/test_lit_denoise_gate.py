"""``auto_denoise_lit_max_snr`` (canopy.enhance.snr.lit_denoise_wanted, s16-darkhaze): with
``auto_denoise_lit`` a well-lit noisy frame is denoised only when its texture SNR is at most the bound.
A real KITTI 06 frame from ``data/`` with the grid's noisy sensor, clear and behind haze β 0.06 /m
(depth from SGBM on the clean pair, as the grid makes it): haze lowers the texture SNR (the
transmission scales the texture, the sensor noise stays), so a bound between the two denoises the
hazy frame only; ``auto`` and the pair enhancer agree; the default (bound 0) is s11's rule."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image, depth_from_stereo, ray_length
from canopy.enhance import EnhanceParams
from canopy.enhance.auto import auto_treat
from canopy.enhance.noise import estimate_noise
from canopy.enhance.pair import PairEnhancer
from canopy.enhance.snr import texture_snr
from canopy.sources import open_source
from shared.errors import ConfigError

KITTI = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet"


def _frames():
    src = open_source("kitti", KITTI)
    f = src.frame(10)
    ray = ray_length(depth_from_stereo(f.left, f.right, src.calibration), src.calibration)
    out = {}
    for name, mode, beta in (("clear", "noise", 0.001), ("hazy", "haze+noise", 0.06)):
        cell = DegradeParams(mode=mode, beta=beta, full_well=NOISE_LEVELS["high"][0], read_noise=NOISE_LEVELS["high"][1])
        out[name] = (degrade_image(f.left, cell, ray, rng=0), degrade_image(f.right, cell, ray, rng=1))
    return out


def test_haze_lowers_the_texture_snr_and_the_bound_denoises_only_the_hazy_frame():
    frames = _frames()
    snr = {k: texture_snr(v[0], estimate_noise(v[0], rows_fraction=0.5)) for k, v in frames.items()}
    assert snr["hazy"] * 2.5 < snr["clear"], snr  # 130 against 630 here
    bound = float(np.sqrt(snr["hazy"] * snr["clear"]))  # between the two
    rule = EnhanceParams(method="auto", auto_denoise_lit=True, auto_denoise_lit_max_snr=bound)
    s11 = EnhanceParams(method="auto", auto_denoise_lit=True)
    for name, (left, right) in frames.items():
        _, decision, sigma, _ = auto_treat(left, rule)
        _, _, info = PairEnhancer(rule)(left, right)
        want = "none>dn" if name == "hazy" else "none"
        assert decision == want and info["method"] == want, (name, decision, info["method"])
        assert (sigma > 0) == (name == "hazy")
        # s11's rule (no bound) denoises both; the default config denoises neither, pixels untouched
        assert auto_treat(left, s11)[1] == "none>dn"
        out, decision, _, _ = auto_treat(left, EnhanceParams(method="auto"))
        assert decision == "none" and np.array_equal(out, left)


def test_bad_bound_is_refused():
    with pytest.raises(ConfigError, match="auto_denoise_lit_max_snr"):
        replace(EnhanceParams(), auto_denoise_lit_max_snr=float("nan")).validate()
