"""Enhancement methods (canopy.enhance) against slow, independent reference implementations.

The references below follow the papers' equations directly, in float64 with
plain loops, on small crops of real images; the fast implementations must
match them within one grey level. Real images come from the project's own
``data/`` (EuRoC, KITTI, LOL, LIME/DICM, O-HAZE pairs; provenance in
``data/README.md``).
"""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.enhance import (AUTO_DECISIONS, ENHANCE_METHODS, EnhanceParams, adaptive_fast_threshold,
                            agcwd_unsharp, auto, auto_decide, auto_full, clahe, dehaze_dark_channel,
                            dehaze_inverted, denoise, estimate_noise,
                            detect_orb_adaptive, fallback_fast_threshold, histogram_equalise,
                            make_enhancer, none)
from shared.errors import ConfigError, InputError
from shared.params import params_from_mapping

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data"


def _data(rel: str) -> Path:
    path = DATA / rel
    if not path.exists():
        raise FileNotFoundError(f"test data missing: {path} (the project ships it under data/)")
    return path


def _read(path: Path, flags=cv2.IMREAD_COLOR) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    assert image is not None, f"cannot read {path}"
    return image


EUROC = _data("euroc_v101_micro/mav0/cam0/data/1403715273262142976.png")
KITTI = _data("kitti06_snippet/image_l/000000.png")
LOL_LOW = _data("lol_pair_778/img/778_input.png")
LOL_HIGH = _data("lol_pair_778/img/778.png")
DICM = _data("lowlight_lime_dicm/Zero-DCE_code/data/test_data/DICM/03.jpg")
HAZE_IDS = ("27", "35")


def _haze_pair(name: str, scale: int = 8) -> tuple[np.ndarray, np.ndarray]:
    hazy = _read(_data(f"haze_pairs/hazy/{name}_outdoor_hazy.jpg"))
    clear = _read(_data(f"haze_pairs/clear/{name}_outdoor_GT.jpg"))
    size = (hazy.shape[1] // scale, hazy.shape[0] // scale)
    return (cv2.resize(hazy, size, interpolation=cv2.INTER_AREA),
            cv2.resize(clear, size, interpolation=cv2.INTER_AREA))


def _crop(image: np.ndarray, y: int, x: int, h: int = 40, w: int = 60) -> np.ndarray:
    return np.ascontiguousarray(image[y:y + h, x:x + w])


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10.0 * math.log10(255.0 ** 2 / mse)


def _assert_close(ours: np.ndarray, ref: np.ndarray, tol: int = 1):
    assert ours.dtype == np.uint8 and ours.shape == ref.shape
    diff = np.abs(ours.astype(np.int32) - ref.astype(np.int32))
    assert diff.max() <= tol, f"max abs diff {diff.max()} at {np.unravel_index(diff.argmax(), diff.shape)}"


# ---------------------------------------------------------------- references

def ref_dehaze(x: np.ndarray, omega: float, block: int, n_dark: int, t0: float) -> np.ndarray:
    """Dark channel prior on ``x`` (AGRI Eq. 2–4), float64 loops; returns float J (unclipped)."""
    x = x.astype(np.float64)
    if x.ndim == 2:
        x = x[:, :, None]
    h, w, c = x.shape
    r = block // 2
    block_min = np.empty_like(x)   # min over the window (clipped at the borders), per channel
    for m in range(h):
        for n in range(w):
            win = x[max(0, m - r):m + r + 1, max(0, n - r):n + r + 1, :]
            for ch in range(c):
                block_min[m, n, ch] = win[:, :, ch].min()
    dark = block_min.min(axis=2)
    # A: the n_dark highest dark-channel values (ties at the n-th kept), then the largest channel sum.
    v_star = np.sort(dark.ravel())[::-1][min(n_dark, dark.size) - 1]
    best, a = -1.0, None
    for m in range(h):
        for n in range(w):
            if dark[m, n] >= v_star and x[m, n].sum() > best:
                best, a = x[m, n].sum(), x[m, n].copy()
    a = np.maximum(a, 1.0)
    j = np.empty_like(x)
    for m in range(h):
        for n in range(w):
            t = 1.0 - omega * min(block_min[m, n, ch] / a[ch] for ch in range(c))   # Eq. 3
            t = min(1.0, max(t0, t))
            for ch in range(c):
                j[m, n, ch] = (x[m, n, ch] - a[ch]) / t + a[ch]                    # Eq. 4
    return j[:, :, 0] if c == 1 else j


def _to_u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.floor(x + 0.5), 0, 255).astype(np.uint8)


def ref_agri(p: np.ndarray, params: EnhanceParams) -> np.ndarray:
    q = 255.0 - p.astype(np.float64)                                              # Eq. 1
    j = ref_dehaze(q, params.omega, params.block, params.n_dark_pixels, params.t0)
    return _to_u8(255.0 - j)                                                      # Eq. 5


def ref_afe(img: np.ndarray, params: EnhanceParams) -> np.ndarray:
    """AFE Eq. 1–17 on a grey image, straight from the paper."""
    i = img.astype(np.float64)
    h, w = i.shape
    lam = i.std() / 255.0                                                         # λ
    bright = (i.mean() - 128.0) / 128.0 >= 0.0                                    # Eq. 7–8
    work = 255.0 - i if bright else i                                             # Eq. 11
    counts = np.zeros(256)
    for v in work.ravel():
        counts[int(v)] += 1
    pdf = counts / work.size                                                      # Eq. 2
    if pdf.max() > pdf.min():
        pwd = pdf.max() * ((pdf - pdf.min()) / (pdf.max() - pdf.min())) ** params.wd_exponent  # Eq. 3
    else:
        pwd = pdf
    ice = np.empty_like(i)
    for m in range(h):
        for n in range(w):
            lv = int(work[m, n])
            cdf = pwd[:lv + 1].sum() / pwd.sum()                                  # Eq. 4–5
            gamma = max(params.tau, 1.0 - cdf)                                    # Eq. 6, 9
            ice[m, n] = 255.0 * (lv / 255.0) ** gamma                             # Eq. 10
    if bright:
        ice = 255.0 - ice
    t_mask = ice - i                                                              # Eq. 12
    s = params.usm_sigma
    r = int(math.ceil(3 * s))
    kernel = np.array([[math.exp(-(x * x + y * y) / (2 * s * s)) for x in range(-r, r + 1)]
                       for y in range(-r, r + 1)])                                # Eq. 16
    kernel /= kernel.sum()
    padded = np.pad(i, r, mode="reflect")                                         # reflect-101
    f = np.empty_like(i)
    for m in range(h):
        for n in range(w):
            f[m, n] = (padded[m:m + 2 * r + 1, n:n + 2 * r + 1] * kernel).sum()   # Eq. 13
    g_mask = i - f                                                                # Eq. 14
    out = i + params.usm_alpha * g_mask                                           # Eq. 15, 17
    if lam <= params.low_contrast_lambda:
        out = out + params.usm_beta * t_mask
    return _to_u8(out)


def ref_equalize_hist(img: np.ndarray) -> np.ndarray:
    """Global HE with OpenCV's normalisation (first occupied level maps to 0)."""
    hist = np.bincount(img.ravel(), minlength=256)
    first = int(np.nonzero(hist)[0][0])
    if hist[first] == img.size:
        return img.copy()
    scale = 255.0 / (img.size - hist[first])
    lut = np.zeros(256)
    total = 0
    for v in range(first + 1, 256):
        total += hist[v]
        lut[v] = total * scale
    return _to_u8(lut[img])


def ref_clahe(img: np.ndarray, clip: float, tiles: int) -> np.ndarray:
    """CLAHE (Zuiderveld) as OpenCV defines it: reflect-pad to whole tiles, clip and
    redistribute each tile's histogram, bilinear interpolation between tile mappings."""
    h, w = img.shape
    ext = img
    if h % tiles or w % tiles:
        # OpenCV pads by tiles - (size % tiles) on both axes, a whole extra tile on an axis that divides
        ext = np.pad(img, ((0, tiles - h % tiles), (0, tiles - w % tiles)), mode="reflect")
    th, tw = ext.shape[0] // tiles, ext.shape[1] // tiles
    area = th * tw
    limit = max(int(clip * area / 256), 1)
    luts = np.zeros((tiles, tiles, 256))
    for ty in range(tiles):
        for tx in range(tiles):
            hist = np.bincount(ext[ty * th:(ty + 1) * th, tx * tw:(tx + 1) * tw].ravel(), minlength=256)
            clipped = int(np.maximum(hist - limit, 0).sum())
            hist = np.minimum(hist, limit)
            batch, residual = clipped // 256, clipped % 256
            hist = hist + batch
            if residual:
                step = max(256 // residual, 1)
                for v in range(0, 256, step):
                    if residual <= 0:
                        break
                    hist[v] += 1
                    residual -= 1
            luts[ty, tx] = np.clip(np.floor(np.cumsum(hist) * (255.0 / area) + 0.5), 0, 255)
    out = np.empty((h, w))
    for y in range(h):
        tyf = y / th - 0.5
        ty1 = math.floor(tyf)
        ya = tyf - ty1
        ty1, ty2 = max(ty1, 0), min(ty1 + 1, tiles - 1)
        for x in range(w):
            txf = x / tw - 0.5
            tx1 = math.floor(txf)
            xa = txf - tx1
            tx1, tx2 = max(tx1, 0), min(tx1 + 1, tiles - 1)
            v = img[y, x]
            out[y, x] = ((luts[ty1, tx1, v] * (1 - xa) + luts[ty1, tx2, v] * xa) * (1 - ya)
                         + (luts[ty2, tx1, v] * (1 - xa) + luts[ty2, tx2, v] * xa) * ya)
    return _to_u8(out)


# ---------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def crops() -> dict[str, np.ndarray]:
    euroc = _read(EUROC, cv2.IMREAD_GRAYSCALE)
    kitti = _read(KITTI, cv2.IMREAD_GRAYSCALE)
    lol = _read(LOL_LOW)
    dicm = _read(DICM)
    hazy, _ = _haze_pair("35", scale=4)
    return {
        "euroc_bright": _crop(euroc, 280, 480),        # mean > 128: AFE's negative-image branch
        "kitti_grey": _crop(kitti, 150, 600),
        "lol_dark_grey": _crop(_grey(lol), 150, 250),  # very dark: AGRI's use case
        "dicm_dark_grey": _crop(_grey(dicm), 300, 300),
        "lol_dark_colour": _crop(lol, 150, 250),
        "hazy_colour": _crop(hazy, 100, 150),
    }


GREY_CROPS = ("euroc_bright", "kitti_grey", "lol_dark_grey", "dicm_dark_grey")


# ---------------------------------------------------------------- method vs reference

@pytest.mark.parametrize("name", GREY_CROPS + ("lol_dark_colour", "hazy_colour"))
def test_agri_matches_reference(crops, name):
    params = EnhanceParams()
    _assert_close(dehaze_inverted(crops[name], params), ref_agri(crops[name], params))


@pytest.mark.parametrize("name", ("hazy_colour", "euroc_bright"))
def test_dark_channel_dehaze_matches_reference(crops, name):
    params = EnhanceParams()
    ref = _to_u8(ref_dehaze(crops[name], params.omega, params.block, params.n_dark_pixels, params.t0))
    _assert_close(dehaze_dark_channel(crops[name], params), ref)


def test_agri_non_default_parameters_match_reference(crops):
    params = EnhanceParams(omega=0.95, block=5, n_dark_pixels=17, t0=0.3)
    _assert_close(dehaze_inverted(crops["kitti_grey"], params), ref_agri(crops["kitti_grey"], params))


@pytest.mark.parametrize("name", GREY_CROPS)
def test_afe_matches_reference(crops, name):
    params = EnhanceParams()
    _assert_close(agcwd_unsharp(crops[name], params), ref_afe(crops[name], params))


def test_afe_high_contrast_branch_matches_reference():
    # λ > 0.25: Eq. 17's second case (sharpening only).
    rng = np.random.default_rng(7)
    img = np.where(rng.random((40, 60)) < 0.5, 20, 235).astype(np.uint8)
    params = EnhanceParams(usm_sigma=1.5, wd_exponent=0.5)
    assert img.std() / 255.0 > params.low_contrast_lambda
    _assert_close(agcwd_unsharp(img, params), ref_afe(img, params))


def test_afe_both_brightness_branches_exercised(crops):
    assert crops["euroc_bright"].mean() >= 128 and crops["lol_dark_grey"].mean() < 128
    for name in ("euroc_bright", "lol_dark_grey"):
        assert crops[name].std() / 255.0 <= EnhanceParams().low_contrast_lambda


@pytest.mark.parametrize("name", GREY_CROPS)
def test_he_matches_reference(crops, name):
    _assert_close(histogram_equalise(crops[name]), ref_equalize_hist(crops[name]))


@pytest.mark.parametrize("name", GREY_CROPS)
def test_clahe_matches_reference(crops, name):
    params = EnhanceParams()
    _assert_close(clahe(crops[name], params), ref_clahe(crops[name], params.clahe_clip, params.clahe_tiles))


def test_colour_methods_work_on_luma(crops):
    img = crops["lol_dark_colour"]
    for fn in (agcwd_unsharp, histogram_equalise, clahe):
        out = fn(img)
        assert out.shape == img.shape and out.dtype == np.uint8
        # the grey level changed the way the grey method changes it (within colour round trips)
        ours = _grey(out).astype(int)
        grey_only = fn(_grey(img)).astype(int)
        assert np.abs(ours - grey_only).mean() < 3.0


def test_none_returns_input(crops):
    img = crops["kitti_grey"]
    assert none(img) is img


# ---------------------------------------------------------------- edge cases

def _edge_images():
    cases = {
        "black": np.zeros((12, 17), np.uint8),
        "white": np.full((12, 17), 255, np.uint8),
        "single": np.full((12, 17), 37, np.uint8),
        "1x1": np.full((1, 1), 200, np.uint8),
        "1x1_black": np.zeros((1, 1), np.uint8),
        # 4x1 and 1x1: the shapes OpenCV's Python binding confuses with a cv::Scalar (4x1) when an
        # array meets a Python number in cv2.add/divide (5.0 rejected 4x1, 5.1 returned 4x1 for 1x1)
        "4x1": np.full((4, 1), 200, np.uint8),
        "4x1_black": np.zeros((4, 1), np.uint8),
        "1xN": np.arange(0, 250, 10, dtype=np.uint8)[None, :],
        "Nx1": np.arange(0, 250, 10, dtype=np.uint8)[:, None],
        "ramp256": np.arange(256, dtype=np.uint8)[None, :],   # flat histogram: Eq. 3 is 0/0
    }
    for key in list(cases):
        cases[key + "_bgr"] = np.repeat(cases[key][:, :, None], 3, axis=2)
    cases["colour_const"] = np.tile(np.array([10, 200, 90], np.uint8), (5, 6, 1))
    return cases


EDGE = _edge_images()
ALL_FUNCTIONS = {"none": none, "he": histogram_equalise, "clahe": clahe, "afe": agcwd_unsharp,
                 "agri": dehaze_inverted, "dehaze": dehaze_dark_channel,
                 "auto": lambda img, p=None: auto(img, p)[0]}


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("case", sorted(EDGE))
@pytest.mark.parametrize("method", sorted(ALL_FUNCTIONS))
def test_edge_cases_valid_output(method, case):
    img = EDGE[case]
    with np.errstate(all="raise"):
        out = ALL_FUNCTIONS[method](img, EnhanceParams())
    assert out.dtype == np.uint8 and out.shape == img.shape


def test_edge_case_values_are_sensible():
    black, white = EDGE["black"], EDGE["white"]
    for fn in (dehaze_inverted, agcwd_unsharp):
        assert (fn(black) == 0).all() and (fn(white) == 255).all()
    single = EDGE["single"]
    assert (agcwd_unsharp(single) == agcwd_unsharp(single)[0, 0]).all()


@pytest.mark.parametrize("bad, problem", [
    (np.zeros((4, 4), np.float32), "dtype"),
    (np.zeros((4, 4), np.int16), "dtype"),
    (np.zeros((4, 4, 4), np.uint8), "shape"),
    (np.zeros((2, 4, 4, 3), np.uint8), "shape"),
    (np.zeros((4,), np.uint8), "shape"),
    (np.zeros((0, 5), np.uint8), "empty"),
    ([[1, 2], [3, 4]], "numpy array"),
])
@pytest.mark.parametrize("method", sorted(ALL_FUNCTIONS))
def test_bad_input_raises_input_error(method, bad, problem):
    with pytest.raises(InputError) as info:
        ALL_FUNCTIONS[method](bad, EnhanceParams())
    assert info.value.source == "image" and problem in info.value.problem
    assert not isinstance(info.value, ConfigError)


# ---------------------------------------------------------------- quality on real pairs

@pytest.mark.parametrize("name", HAZE_IDS)
def test_dehazing_raises_psnr_on_real_hazy_pairs(name):
    hazy, clear = _haze_pair(name)
    before = _psnr(hazy, clear)
    assert _psnr(dehaze_dark_channel(hazy), clear) > before + 1.0
    out, decision = auto(hazy)
    assert decision in ("dehaze", "dehaze>dn") and _psnr(out, clear) > before + 1.0
    grey_hazy, grey_clear = _grey(hazy), _grey(clear)
    assert _psnr(dehaze_dark_channel(grey_hazy), grey_clear) > _psnr(grey_hazy, grey_clear)


@pytest.mark.parametrize("colour", (True, False))
def test_low_light_enhancement_raises_psnr_on_lol_pair(colour):
    low, high = _read(LOL_LOW), _read(LOL_HIGH)
    if not colour:
        low, high = _grey(low), _grey(high)
    before = _psnr(low, high)
    for fn in (dehaze_inverted, agcwd_unsharp):
        assert _psnr(fn(low), high) > before + 1.0, fn.__name__


# ---------------------------------------------------------------- auto and factory

def test_auto_decisions_on_real_images():
    params = EnhanceParams(method="auto")
    assert auto_decide(_read(EUROC, cv2.IMREAD_GRAYSCALE), params)[0] == "none"
    assert auto_decide(_read(KITTI, cv2.IMREAD_GRAYSCALE), params)[0] == "none"
    assert auto_decide(_read(LOL_LOW), params)[0] == "afe"      # the dark branch (auto_dark_method)
    assert auto_decide(_grey(_read(LOL_LOW)), params)[0] == "afe"
    assert auto_decide(_read(LOL_LOW), EnhanceParams(auto_dark_method="agri"))[0] == "agri"
    for name in HAZE_IDS:
        hazy, clear = _haze_pair(name)
        assert auto_decide(hazy, params)[0] == "dehaze"
        assert auto_decide(clear, params)[0] != "dehaze"
    rng = np.random.default_rng(3)
    dull = cv2.resize(rng.integers(70, 100, (10, 15)).astype(np.uint8), (60, 40),
                      interpolation=cv2.INTER_NEAREST)     # mean ~85, std ~9, dark channel ~70
    assert auto_decide(dull, params)[0] == "afe"          # low contrast, no haze signature
    assert auto_decide(np.full((40, 60), 240, np.uint8), params)[0] == "dehaze"


def test_auto_well_lit_passes_through():
    img = _read(EUROC, cv2.IMREAD_GRAYSCALE)
    out, decision = auto(img, EnhanceParams())
    assert decision == "none" and out is img


@pytest.mark.parametrize("method", ENHANCE_METHODS)
def test_make_enhancer_info(method):
    img = _read(LOL_LOW)
    enhance = make_enhancer(EnhanceParams(method=method))
    out, info = enhance(img)
    assert out.shape == img.shape and out.dtype == np.uint8
    assert set(info) == {"method", "requested", "mean_in", "std_in", "mean_out", "std_out", "noise_sigma", "gamma",
                         "eps_factor", "ms"}
    assert info["requested"] == method and info["ms"] >= 0.0
    assert info["eps_factor"] == (2.0 if method == "auto" else 0.0)  # the denoiser's default factor (s15-snr)
    assert info["method"] == ("afe>dn" if method == "auto" else method)  # LOL: dark and noisy
    assert (info["noise_sigma"] > 0) == (method == "auto")
    assert info["method"] in AUTO_DECISIONS + ENHANCE_METHODS
    assert info["mean_in"] == pytest.approx(float(_grey(img).mean()), abs=0.01)
    if method in ("agri", "afe", "he", "clahe", "auto"):
        assert info["mean_out"] > info["mean_in"]


# ---------------------------------------------------------------- adaptive FAST threshold

def test_adaptive_fast_threshold_formula():
    half = np.zeros((10, 10), np.uint8)
    half[:, 5:] = 255                                       # σ = 127.5, λ = 0.5
    assert adaptive_fast_threshold(half) == 128 * 0.5 + 20 == 84    # Eq. 18
    assert fallback_fast_threshold(half) == 128 * 0.5 / 2 == 32     # Eq. 19
    assert adaptive_fast_threshold(half, omega=64.0) == 52
    flat = np.full((10, 10), 90, np.uint8)                  # λ = 0
    assert adaptive_fast_threshold(flat) == 20
    assert fallback_fast_threshold(flat) == 1               # clamped up from 0
    assert adaptive_fast_threshold(half, omega=1000.0) == 255   # clamped down
    img = _read(EUROC, cv2.IMREAD_GRAYSCALE)
    lam = img.astype(np.float64).std() / 255.0
    assert adaptive_fast_threshold(img) == round(128 * lam + 20)
    assert fallback_fast_threshold(img) == round(128 * lam / 2)


def test_detect_orb_adaptive_sets_threshold_and_falls_back():
    img = _read(EUROC, cv2.IMREAD_GRAYSCALE)
    params = EnhanceParams()
    orb = cv2.ORB_create(nfeatures=500)
    kps, desc, theta = detect_orb_adaptive(img, orb, params, min_keypoints=0)
    assert theta == adaptive_fast_threshold(img) == orb.getFastThreshold()
    assert len(kps) > 0 and desc.shape == (len(kps), 32)
    kps2, _, theta2 = detect_orb_adaptive(img, orb, params, min_keypoints=10 ** 6)
    assert theta2 == fallback_fast_threshold(img) == orb.getFastThreshold()
    assert len(kps2) >= len(kps)
    orb.setFastThreshold(20)
    _, _, theta3 = detect_orb_adaptive(img, orb, EnhanceParams(adaptive_fast=False))
    assert theta3 == 20 == orb.getFastThreshold()


def test_adaptive_fast_keeps_features_on_dark_image():
    dark = _grey(_read(LOL_LOW))
    orb = cv2.ORB_create(nfeatures=1000)
    fixed = len(orb.detect(dark, None))                    # OpenCV's fixed θ = 20
    kps, _, theta = detect_orb_adaptive(dark, orb, EnhanceParams(), min_keypoints=200)
    assert theta < 20 and len(kps) > fixed


# ---------------------------------------------------------------- parameters

def test_params_defaults_are_the_papers():
    p = EnhanceParams()
    assert (p.omega, p.block, p.n_dark_pixels, p.t0) == (0.8, 9, 200, 0.1)
    assert (p.tau, p.usm_alpha, p.usm_beta, p.fast_omega) == (0.3, 1.0, 0.3, 128.0)
    assert (p.clahe_clip, p.clahe_tiles, p.method) == (2.0, 8, "none")


@pytest.mark.parametrize("field, value", [
    ("method", "sharpen"), ("omega", 0.0), ("omega", 1.5), ("omega", float("nan")),
    ("block", 8), ("block", 0), ("block", -3), ("n_dark_pixels", 0), ("t0", 0.0), ("t0", 1.2),
    ("tau", -0.1), ("tau", 1.1), ("wd_exponent", 0.0), ("usm_sigma", 0.0), ("usm_alpha", -1.0),
    ("clahe_clip", 0.0), ("clahe_tiles", 0), ("auto_downsample", 0), ("auto_dark_mean", 300.0),
    ("auto_dark_mean", 250.0), ("fast_omega", float("inf")), ("min_keypoints", -1),
    ("block", 9.0), ("adaptive_fast", 1), ("denoise_radius", 0), ("denoise_eps_factor", 0.0),
    ("auto_noise_sigma", -1.0), ("auto_dark_method", "clahe"), ("auto_denoise_lit", 1), ("auto_dark_min_sigma", float("nan")), ("auto_dehaze_max_clip", 1.5),
])
def test_params_validation(field, value):
    with pytest.raises(ConfigError) as info:
        EnhanceParams(**{field: value})
    assert field in info.value.source


def test_params_from_yaml_mapping():
    p = params_from_mapping(EnhanceParams, {"method": "agri", "omega": 0.9, "block": 15}, "enhance.yaml")
    assert (p.method, p.omega, p.block) == ("agri", 0.9, 15)
    with pytest.raises(ConfigError, match="unknown"):
        params_from_mapping(EnhanceParams, {"omegaa": 0.9}, "enhance.yaml")
    with pytest.raises(ConfigError, match="block"):
        params_from_mapping(EnhanceParams, {"block": "9"}, "enhance.yaml")
    with pytest.raises(ConfigError, match="method"):
        params_from_mapping(EnhanceParams, {"method": "magic"}, "enhance.yaml")


# ---------------------------------------------------------------- noise-aware enhancement (issue 9)

def _with_noise(image: np.ndarray, sigma: float, seed: int = 0) -> np.ndarray:
    noisy = image.astype(np.float64) + np.random.default_rng(seed).normal(0.0, sigma, image.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("path", [KITTI, EUROC])
def test_noise_estimate_recovers_added_noise_on_real_frames(path):
    img = _read(path, cv2.IMREAD_GRAYSCALE)
    floor = estimate_noise(img)                    # texture + the camera's own noise
    assert 1.0 < floor < 2.5
    for sigma in (4.0, 8.0, 16.0):
        measured = estimate_noise(_with_noise(img, sigma))
        expected = math.hypot(sigma, floor)        # independent noises add in variance
        assert measured == pytest.approx(expected, rel=0.15), sigma


def test_noise_estimate_edge_cases():
    assert estimate_noise(np.full((2, 2), 7, np.uint8)) == 0.0
    assert estimate_noise(np.full((50, 50), 128, np.uint8)) == 0.0
    steps = np.tile(np.repeat(np.arange(0, 250, 50, dtype=np.uint8), 10), (50, 1))  # edges, no noise
    assert estimate_noise(steps) < 0.5
    with pytest.raises(InputError):
        estimate_noise(np.zeros((20, 20), np.float32))


def test_denoise_smooths_flat_areas_and_keeps_edges():
    step = np.full((80, 120), 60, np.uint8)
    step[:, 60:] = 160                             # a 100-level edge
    noisy = _with_noise(step, 6.0, seed=1)
    sigma = estimate_noise(noisy)
    assert sigma == pytest.approx(6.0, rel=0.15)
    out = denoise(noisy, sigma)
    assert out.dtype == np.uint8 and out.shape == noisy.shape
    flat = np.s_[10:70, 5:50]
    assert out[flat].std() < 0.5 * noisy[flat].std()
    # the edge stays where it was and as high as it was
    profile = out[10:70].mean(axis=0)
    assert profile[57] < 75 and profile[62] > 145
    assert denoise(noisy, 0.0) is noisy


def test_noise_estimate_on_a_central_band_agrees_with_the_whole_frame():
    img = _read(KITTI, cv2.IMREAD_GRAYSCALE)
    for sigma in (4.0, 12.0):
        noisy = _with_noise(img, sigma, seed=3)
        assert estimate_noise(noisy, rows_fraction=0.5) == pytest.approx(estimate_noise(noisy), rel=0.1)
    with pytest.raises(ConfigError):
        EnhanceParams(noise_rows_fraction=0.0)


def _guided_reference(grey: np.ndarray, radius: int, eps: float, s: int) -> np.ndarray:
    """He & Sun's fast guided filter (guide = input) in float64: coefficients on the s-times
    block-averaged image with radius r/s (box means, replicated borders as cv2.boxFilter's
    default reflect-101), upsampled bilinearly, q = ā·I + b̄ at full resolution."""
    h, w = grey.shape
    small = grey.reshape(h // s, s, w // s, s).astype(np.float64).mean(axis=(1, 3))
    r = max(1, round(radius / s))
    k = (2 * r + 1, 2 * r + 1)
    mean = cv2.boxFilter(small, cv2.CV_64F, k)
    var = cv2.boxFilter(small * small, cv2.CV_64F, k) - mean * mean
    a = var / (var + eps)
    b = mean - a * mean
    a, b = (cv2.resize(cv2.boxFilter(x, cv2.CV_64F, k), (w, h), interpolation=cv2.INTER_LINEAR) for x in (a, b))
    return np.clip(a * grey + b, 0, 255)


def test_guided_filter_fixed_point_matches_the_float_filter():
    from canopy.enhance.noise import guided_self_filter
    img = _read(KITTI, cv2.IMREAD_GRAYSCALE)[:200, :400]
    noisy = _with_noise(img, 10.0, seed=4)
    for eps in (64.0, 400.0):
        fast = guided_self_filter(noisy, 2, eps, 2).astype(np.float64)
        ref = _guided_reference(noisy, 2, eps, 2)
        err = np.abs(fast - ref)
        assert err.max() <= 2.0 and err.mean() < 0.4, eps  # 8-bit ā, b̄ and output: each rounds by ≤ ½


def _stereo_correct(left, right, ref_disp, adaptive: bool):
    """Correct stereo matches of the tracking front end (disparity within 1 px of the reference),
    with the FAST threshold the tracking actor uses: AFE Eq. 18, Eq. 19 below ``min_keypoints``
    (``adaptive``), or the fixed one (``--enhance none``)."""
    from canopy.config import load_run_config
    from canopy.frontend.features import OrbExtractor
    from canopy.frontend.stereo import match_stereo
    from canopy.sources import open_source

    calib = open_source("kitti").calibration
    tracking = load_run_config("kitti").tracking
    if adaptive:
        args = (adaptive_fast_threshold(left), fallback_fast_threshold(left), EnhanceParams().min_keypoints)
    else:
        args = ()
    fl = OrbExtractor(tracking).extract(left, *args)
    fr = OrbExtractor(tracking).extract(right, *args)
    st = match_stereo(fl, fr, left, right, calib, tracking)
    uv = fl.uv[st.valid]
    d = uv[:, 0] - st.u_right[st.valid]
    ref = ref_disp[np.rint(uv[:, 1]).astype(int), np.rint(uv[:, 0]).astype(int)]
    return int(np.sum((ref > 0) & (np.abs(d - ref) <= 1.0)))


def test_auto_denoises_a_dark_noisy_real_pair_into_more_correct_stereo_matches():
    """What tracking needs: on a KITTI pair at 6 % light with a noisy sensor, the pair as the
    enhancement actor treats it (auto decides on the left, the right gets the same decision and σ)
    gives more stereo matches at the right disparity (SGBM on the clean pair) than AGRI alone."""
    from canopy.degrade import DegradeParams, degrade_image, disparity_sgbm

    left = _read(KITTI, cv2.IMREAD_GRAYSCALE)
    right = _read(_data("kitti06_snippet/image_r/000000.png"), cv2.IMREAD_GRAYSCALE)
    ref = disparity_sgbm(left, right)
    cell = DegradeParams(mode="dark", gain=0.06, full_well=1000.0, read_noise=10.0)
    dl, dr = degrade_image(left, cell, rng=1), degrade_image(right, cell, rng=2)
    params = EnhanceParams(method="auto")
    enhance = make_enhancer(params)
    al, info = enhance(dl)
    ar, info_r = enhance(dr, method=info["method"], noise_sigma=info["noise_sigma"])
    assert info["method"] == info_r["method"] == "afe>dn"
    assert info_r["noise_sigma"] == info["noise_sigma"] > 0
    auto_correct = _stereo_correct(al, ar, ref, True)
    afe_correct = _stereo_correct(agcwd_unsharp(dl), agcwd_unsharp(dr), ref, True)  # AFE alone
    none_correct = _stereo_correct(dl, dr, ref, False)
    assert none_correct < 20                      # raw: FAST finds (almost) nothing
    assert auto_correct >= 1.5 * max(afe_correct, 1), (auto_correct, afe_correct)


def test_auto_leaves_clean_real_frames_alone():
    params = EnhanceParams(method="auto")
    for path in (KITTI, EUROC, _data("kitti06_snippet/image_r/000000.png")):
        img = _read(path, cv2.IMREAD_GRAYSCALE)
        out, decision, sigma = auto_full(img, params)
        assert decision == "none" and sigma == 0.0 and out is img


def test_auto_denoises_well_lit_noisy_frames_only_when_asked():
    img = _with_noise(_read(KITTI, cv2.IMREAD_GRAYSCALE), 8.0)
    out, decision, sigma = auto_full(img, EnhanceParams())
    assert decision == "none" and out is img and sigma == 0.0
    out, decision, sigma = auto_full(img, EnhanceParams(auto_denoise_lit=True))
    assert decision == "none>dn" and sigma > EnhanceParams().auto_noise_sigma
    assert estimate_noise(out) < 0.6 * estimate_noise(img)


def test_auto_dehaze_guard_falls_back_to_afe():
    hazy, clear = _haze_pair("27")
    assert auto_full(hazy, EnhanceParams())[1].startswith("dehaze")
    # a guard that tolerates no extra clipping at all: a dehazed frame that clips is refused
    dehazed = dehaze_dark_channel(hazy)
    clip = lambda x: np.mean((_grey(x) == 0) | (_grey(x) == 255))  # noqa: E731
    if clip(dehazed) > clip(hazy):
        assert auto_full(hazy, EnhanceParams(auto_dehaze_max_clip=0.0))[1].startswith("afe")
    bright_sky = hazy.copy()
    bright_sky[: hazy.shape[0] // 2] = 255       # half the frame saturated sky: DCP's failure case
    out, decision, _ = auto_full(bright_sky, EnhanceParams(auto_dehaze_max_clip=0.0))
    assert not decision.startswith("dehaze") or clip(out) <= clip(bright_sky)


def test_enhancer_rejects_unknown_forced_method():
    enhance = make_enhancer(EnhanceParams(method="auto"))
    with pytest.raises(ConfigError, match="method"):
        enhance(np.zeros((10, 10), np.uint8), method="sharpen")
