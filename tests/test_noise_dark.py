"""Dark, noisy frames (issue 9): the exposure curve and denoiser of ``auto``'s dark branch, the
FAST-threshold rule the tracking actor applies to the frames it gets, and the real-pair floors.

Real images only from the project's ``data/`` (provenance in ``data/README.md``).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image
from canopy.enhance import (EnhanceParams, adaptive_fast_threshold, fallback_fast_threshold, make_enhancer,
                            pair_arguments, tracking_fast_arguments)
from canopy.enhance.auto import apply_gamma, exposure_gamma
from shared.errors import ConfigError

DATA = Path(__file__).resolve().parents[1] / "data"
KITTI_L = DATA / "kitti06_snippet" / "image_l" / "000010.png"
KITTI_R = DATA / "kitti06_snippet" / "image_r" / "000010.png"
LOL = DATA / "lol_pair_778" / "img"
HAZE = DATA / "haze_pairs"


def _read(path: Path, flags=cv2.IMREAD_COLOR) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    assert img is not None, f"test data missing: {path} (the project ships it under data/)"
    return img


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10.0 * np.log10(255.0 ** 2 / mse))


def _dark_pair(gain: float = 0.06, noise: str = "high"):
    cell = DegradeParams(mode="dark", gain=gain, full_well=NOISE_LEVELS[noise][0], read_noise=NOISE_LEVELS[noise][1])
    left, right = _read(KITTI_L, cv2.IMREAD_GRAYSCALE), _read(KITTI_R, cv2.IMREAD_GRAYSCALE)
    return degrade_image(left, cell, rng=1), degrade_image(right, cell, rng=2)


def test_exposure_gamma_takes_the_mean_to_the_target_and_is_bounded():
    ramp = np.tile(np.arange(0, 40, dtype=np.uint8), (20, 1))        # mean 19.5
    g = exposure_gamma(ramp, 60.0, 0.4)
    assert 0.4 < g < 1.0
    assert 255.0 * (ramp.mean() / 255.0) ** g == pytest.approx(60.0, rel=1e-6)    # the mean grey goes to 60
    assert float(apply_gamma(ramp, g).mean()) == pytest.approx(60.0, rel=0.1)     # (Jensen: the mean near it)
    assert exposure_gamma(ramp, 200.0, 0.4) == 0.4                    # capped: γ ≥ min_gamma
    assert exposure_gamma(ramp, 0.0, 0.4) == 1.0                      # off
    assert exposure_gamma(np.full((5, 5), 120, np.uint8), 100.0, 0.4) == 1.0   # already bright
    assert exposure_gamma(np.zeros((5, 5), np.uint8), 100.0, 0.4) == 1.0       # black: nothing to lift
    assert apply_gamma(ramp, 1.0) is ramp
    for bad in ({"auto_dark_target_mean": 300.0}, {"auto_dark_min_gamma": 0.0}, {"denoised_fallback_weight": 2.0},
                {"fill_denoised_features": 1}):
        with pytest.raises(ConfigError):
            EnhanceParams(**bad)


def test_dark_pair_is_brightened_denoised_and_both_images_treated_alike():
    left, right = _dark_pair()
    params = EnhanceParams(method="auto")
    enhance = make_enhancer(params)
    le, info = enhance(left)
    re, info_r = enhance(right, **pair_arguments(info))
    assert info["method"] == "afe>dn" and info["gamma"] < 1.0 and info["noise_sigma"] > 0
    assert (info_r["method"], info_r["gamma"], info_r["noise_sigma"]) == \
        (info["method"], info["gamma"], info["noise_sigma"])
    # exposure lifted towards the target, the two views alike
    assert le.mean() > 3 * left.mean() and abs(float(le.mean()) - float(re.mean())) < 3.0
    # the denoiser took the pixel noise down: the Laplacian-difference response (noise) is much
    # weaker relative to the image contrast than on the same frame brightened without denoising
    bright = apply_gamma(make_enhancer(EnhanceParams(method="afe"))(left)[0], info["gamma"])
    mask = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)

    def hf(img):
        return float(np.median(np.abs(cv2.filter2D(img.astype(np.float32), -1, mask))))
    assert hf(le) < 0.5 * hf(bright)


def test_tracking_fast_rule_by_decision():
    left, _ = _dark_pair()
    params = EnhanceParams(method="auto")
    assert tracking_fast_arguments(left, "none", params, 2000) == {}          # untouched frames: fixed θ
    lit = tracking_fast_arguments(left, "afe", params, 2000)
    assert lit == {"fast_threshold": adaptive_fast_threshold(left), "fast_fallback": fallback_fast_threshold(left),
                   "fast_min_keypoints": params.min_keypoints}               # AFE Eq. 18 / 19 as published
    dark = tracking_fast_arguments(left, "afe>dn", params, 2000)
    assert dark["fast_min_keypoints"] == 2000 and dark["fast_threshold"] == lit["fast_threshold"]
    mid = tracking_fast_arguments(left, "afe>dn", EnhanceParams(method="auto", denoised_fallback_weight=1.0), 2000)
    assert mid["fast_fallback"] == lit["fast_threshold"]
    off = tracking_fast_arguments(left, "afe>dn", EnhanceParams(method="auto", fill_denoised_features=False), 2000)
    assert off["fast_min_keypoints"] == params.min_keypoints
    assert tracking_fast_arguments(left, "afe>dn", EnhanceParams(method="auto", adaptive_fast=False), 2000) == {}


def test_auto_on_the_real_low_light_pair_reaches_the_issue_floor():
    low, high = _read(LOL / "778_input.png"), _read(LOL / "778.png")
    out, info = make_enhancer(EnhanceParams(method="auto"))(low)
    assert info["method"].endswith(">dn")
    assert _psnr(out, high) >= 11.4                                            # issue 9
    assert _psnr(out, high) > _psnr(low, high) + 3.0


@pytest.mark.parametrize("name,floor", [("27", 14.47), ("35", 19.55)])
def test_auto_keeps_the_real_haze_floors(name, floor):
    hazy = _read(HAZE / "hazy" / f"{name}_outdoor_hazy.jpg")
    clear = _read(HAZE / "clear" / f"{name}_outdoor_GT.jpg")
    out, _ = make_enhancer(EnhanceParams(method="auto"))(hazy)
    assert _psnr(out, clear) >= floor - 0.01                                   # O-HAZE floors of issue 9
    assert _psnr(out, clear) > _psnr(hazy, clear)                              # never worse than the input


@pytest.mark.parametrize("method", ["auto", "afe"])
def test_pair_enhancer_gives_the_sequential_images(method):
    """The two-thread pair path (the enhancement actor's) = left, then right with the left's
    decision, γ and σ (make_enhancer + pair_arguments): same pixels, same info."""
    from canopy.enhance.pair import PairEnhancer

    clean = (_read(KITTI_L, cv2.IMREAD_GRAYSCALE), _read(KITTI_R, cv2.IMREAD_GRAYSCALE))
    params = EnhanceParams(method=method)
    enhance, pair = make_enhancer(params), PairEnhancer(params)
    try:
        for left, right in (_dark_pair(), clean):
            le, info = enhance(left)
            re, _ = enhance(right, **pair_arguments(info))
            pl, pr, pinfo = pair(left, right)
            assert np.array_equal(pl, le) and np.array_equal(pr, re)
            assert {k: pinfo[k] for k in ("method", "noise_sigma", "gamma")} == \
                {k: info[k] for k in ("method", "noise_sigma", "gamma")}
    finally:
        pair.close()
