"""The enhancement's fast paths (issue 9: ≤ 4 ms per dark stereo pair) compute what the plain
formulas compute: AFE Eq. 17 in int16 arithmetic, Eq. 2's histogram on every 2nd row, the guided
filter's full-resolution product in 8 bits. Real frames from the project's ``data/``, darkened and
noised with ``canopy.degrade`` as in the degradation grid.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image
from canopy.enhance import EnhanceParams
from canopy.enhance.agcwd import _LEVELS, agcwd_unsharp, contrast_curve, gaussian_ksize
from canopy.enhance.noise import guided_self_filter
from canopy.enhance.pair import PairEnhancer
from shared.errors import ConfigError

DATA = Path(__file__).resolve().parents[1] / "data"
FRAMES = {"kitti": (DATA / "kitti06_snippet" / "image_l" / "000010.png",
                    DATA / "kitti06_snippet" / "image_r" / "000010.png"),
          "euroc": (DATA / "euroc_v101_micro" / "mav0" / "cam0" / "data" / "1403715273262142976.png",
                    DATA / "euroc_v101_micro" / "mav0" / "cam1" / "data" / "1403715273262142976.png")}


def _grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None, f"test data missing: {path} (the project ships it under data/)"
    return img


def _dark(img: np.ndarray, gain: float, noise: str, seed: int) -> np.ndarray:
    cell = DegradeParams(mode="dark", gain=gain, full_well=NOISE_LEVELS[noise][0], read_noise=NOISE_LEVELS[noise][1])
    return degrade_image(img, cell, rng=seed)


def _afe_with_add_weighted(grey: np.ndarray, params: EnhanceParams) -> np.ndarray:
    """Eq. 17 as before the int16 path: table(I) by a 16-bit LUT, − α f by cv2.addWeighted."""
    low = float(np.std(grey)) / 255.0 <= params.low_contrast_lambda
    a, b = params.usm_alpha, params.usm_beta
    table = (1 + a - b) * _LEVELS + b * contrast_curve(grey, params) if low else (1 + a) * _LEVELS
    ks = gaussian_ksize(params.usm_sigma)
    blurred = cv2.GaussianBlur(grey, (ks, ks), params.usm_sigma, borderType=cv2.BORDER_REFLECT_101)
    table_i = cv2.LUT(grey, np.rint(table).astype(np.int16).reshape(1, 256))
    return cv2.addWeighted(table_i, 1.0, blurred, -a, 0.0, dtype=cv2.CV_8U)


@pytest.mark.parametrize("alpha", [1.0, 2.0])
@pytest.mark.parametrize("gain,noise", [(0.06, "high"), (0.15, "low"), (1.0, "low")])
def test_afe_int16_path_equals_the_weighted_sum(alpha, gain, noise):
    params = EnhanceParams(usm_alpha=alpha)
    for name, (left, _) in FRAMES.items():
        img = _dark(_grey(left), gain, noise, seed=3)
        fast = agcwd_unsharp(img, params)
        assert fast.dtype == np.uint8 and fast.shape == img.shape
        assert np.array_equal(fast, _afe_with_add_weighted(img, params)), (name, gain, noise, alpha)


def test_afe_non_integer_alpha_stays_within_one_level_of_float_eq17():
    params = EnhanceParams(usm_alpha=0.7)
    img = _dark(_grey(FRAMES["kitti"][0]), 0.06, "high", seed=5)
    grey = img.astype(np.float64)
    table = (1 + 0.7 - 0.3) * _LEVELS + 0.3 * contrast_curve(img, params)   # dark frame: low contrast
    ks = gaussian_ksize(params.usm_sigma)
    blurred = cv2.GaussianBlur(img, (ks, ks), params.usm_sigma, borderType=cv2.BORDER_REFLECT_101)
    ref = np.clip(table[img] - 0.7 * blurred, 0, 255)
    assert np.abs(agcwd_unsharp(img, params) - ref).max() <= 1.0
    assert float(np.std(grey)) / 255.0 <= params.low_contrast_lambda  # the branch with the contrast curve


@pytest.mark.parametrize("gain,noise", [(0.02, "high"), (0.06, "high"), (0.15, "low")])
def test_afe_histogram_on_every_second_row_moves_few_pixels_by_one_level(gain, noise):
    full = EnhanceParams(afe_hist_row_step=1)
    assert EnhanceParams().afe_hist_row_step == 2
    for name, (left, _) in FRAMES.items():
        img = _dark(_grey(left), gain, noise, seed=7)
        diff = np.abs(agcwd_unsharp(img, EnhanceParams()).astype(int) - agcwd_unsharp(img, full).astype(int))
        assert diff.max() <= 1 and (diff > 0).mean() < 0.05, (name, gain, diff.max(), (diff > 0).mean())


def test_guided_filter_uint8_product_equals_the_16_bit_product():
    """ā·I ≤ 255 in 8 bits, rounded, then + b̄ saturated: the same pixels as the 16-bit product."""
    img = _dark(_grey(FRAMES["kitti"][0]), 0.06, "high", seed=9)
    lifted = cv2.LUT(img, np.clip(np.arange(256) * 4, 0, 255).astype(np.uint8))   # the noise amplified
    h, w = lifted.shape
    small = cv2.resize(lifted[: h - h % 2, : w - w % 2], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    eps, k = 40.0 ** 2, (3, 3)
    mean_i = cv2.boxFilter(small, cv2.CV_32F, k)
    var = cv2.subtract(cv2.sqrBoxFilter(small, cv2.CV_32F, k), cv2.multiply(mean_i, mean_i))
    a = cv2.divide(var, cv2.add(var, eps))
    b = cv2.subtract(mean_i, cv2.multiply(a, mean_i))
    a8 = cv2.resize(cv2.convertScaleAbs(cv2.boxFilter(a, -1, k), alpha=255.0), (w, h), interpolation=cv2.INTER_LINEAR)
    b8 = cv2.resize(cv2.convertScaleAbs(cv2.boxFilter(b, -1, k)), (w, h), interpolation=cv2.INTER_LINEAR)
    ref = cv2.add(cv2.multiply(a8, lifted, scale=1 / 255.0, dtype=cv2.CV_16S), b8, dtype=cv2.CV_8U)
    out = guided_self_filter(lifted, 2, eps, 2)
    assert np.array_equal(out, ref)
    assert float(np.std(out)) < float(np.std(lifted))  # and it does smooth


def test_dark_pair_serial_and_two_threads_give_the_same_images():
    left, right = (_dark(_grey(p), 0.06, "high", seed=s) for p, s in zip(FRAMES["euroc"], (1, 2)))
    params = EnhanceParams(method="auto")
    outs = []
    for parallel in (False, True):
        enh = PairEnhancer(params, parallel=parallel)
        try:
            outs.append(enh(left, right))
        finally:
            enh.close()
    (l0, r0, i0), (l1, r1, i1) = outs
    assert i0["method"] == i1["method"] == "afe>dn"
    assert np.array_equal(l0, l1) and np.array_equal(r0, r1)
    assert i0["noise_sigma"] == i1["noise_sigma"] and i0["gamma"] == i1["gamma"]


@pytest.mark.parametrize("value", [0, -2, 1.5, True])
def test_hist_row_step_must_be_a_positive_integer(value):
    with pytest.raises(ConfigError) as info:
        replace(EnhanceParams(), afe_hist_row_step=value)
    assert "afe_hist_row_step" in info.value.source


@pytest.mark.parametrize("value", [0, 3, 2.0, True])
def test_pair_threads_must_be_one_or_two(value):
    with pytest.raises(ConfigError) as info:
        EnhanceParams(pair_threads=value)
    assert "pair_threads" in info.value.source


def test_pair_enhancer_threads_follow_the_parameter():
    for threads, parallel in ((1, False), (2, True)):
        enh = PairEnhancer(EnhanceParams(method="auto", pair_threads=threads))
        try:
            assert (enh._pool is not None) == parallel
        finally:
            enh.close()
