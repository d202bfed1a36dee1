"""Physically based degradation of images: low light and haze (issue 3, item 4).

Pure numpy/OpenCV functions on uint8 grey (H, W) or colour (H, W, 3) images;
``tools/degrade_sequence.py`` applies them to whole datasets.

Low light (``darken``)
    Pixel values are read as linear radiance (after undoing an optional
    encoding gamma), scaled by ``gain`` (0.1 = ten times less light reaches
    the sensor), converted to photo-electrons with ``full_well`` electrons at
    8-bit white, given Poisson shot noise and Gaussian read noise
    (``read_noise`` electrons rms), mapped back to grey levels with the
    *same* conversion (the camera does not raise its exposure) and quantised
    to 8 bits. In grey levels (gamma 1) the result has mean ``gain·v`` and
    variance ``(255/full_well)²·(gain·v·full_well/255 + read_noise²)`` plus
    1/12 for quantisation: noise grows with the signal, as shot noise does.

    Defaults are effective values at 8-bit white, in the range of small-pixel
    machine-vision CMOS sensors (a few thousand electrons of full well, a few
    electrons of read noise); they are parameters, not a claim about the
    EuRoC or KITTI cameras. Gamma 1 treats the stored values as linear, which
    is how machine-vision cameras (EuRoC's MT9V034, KITTI's FL2) usually
    record; use 2.2 for sRGB photos.

Haze (``add_haze``)
    Koschmieder's atmospheric scattering model, the one the dark channel
    prior inverts (AGRI-SLAM Eq. 1): I = J·t + A·(1 − t), t = exp(−β·d),
    with d the length of the viewing ray through the air in metres and A the
    airlight in grey levels. Computed on linear radiance (the same optional
    gamma as ``darken``); with gamma 1 it is the formula on grey levels,
    rounded once to 8 bits.

Depth (``depth_from_stereo``)
    Semi-global matching (cv2.StereoSGBM, 3-way) on the rectified pair,
    depth = bf / disparity. Pixels without a valid disparity (occlusions, the
    left border strip, textureless floor) are filled row by row with the
    farther of the nearest valid disparities on either side (the KITTI
    devkit's background interpolation): calling them all "far" would put full
    airlight on a textureless floor a metre away. Rows with no valid pixel,
    and anything beyond ``max_depth``, get ``max_depth``.
    ``view="right"`` gives the right camera's depth map by matching the
    mirrored pair (right image as reference). ``ray_length`` converts the
    z-depth to the distance along each pixel's ray, which is the path length
    the scattering model needs and, unlike z, does not change when an image
    is rectified (a rotation about the camera centre).

Noise (mode ``noise``)
    The sensor model of ``darken`` at gain 1: shot and read noise on the
    light as recorded. ``dark`` always includes the noise (there is no dark
    exposure without it); ``NOISE_LEVELS`` names the two sensors of the
    degradation grid and ``grid_cells`` lists its cells (light × haze ×
    noise), each a ``DegradeParams``.

Order for ``dark+haze``: haze first (it happens in the scene), then low light
(it happens at the sensor): ``darken(add_haze(J, d, β, A), gain)``.

Errors: parameter values that cannot be used raise ``ConfigError`` naming the
parameter; images of the wrong type raise ``InputError``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from shared.errors import ConfigError, InputError
from shared.types import StereoCalibration

DEGRADE_MODES = ("dark", "haze", "dark+haze", "noise", "haze+noise")
WHITE = 255.0
# Sensor noise levels of the degradation grid (issue 9): effective full well (electrons at
# 8-bit white) and read noise (electrons rms). "low" is DegradeParams' default sensor; "high" a
# smaller pixel with a noisier read-out (4x less full well, 2.5x the read noise).
NOISE_LEVELS = {"low": (4000.0, 4.0), "high": (1000.0, 10.0)}
# The grid's axes: light reaching the sensor (1 = as recorded, with the sensor's noise),
# haze extinction β (1/m, from depth) and the noise level.
GRID_GAINS = (1.0, 0.15, 0.06, 0.02)
GRID_BETAS = (0.0, 0.03, 0.06)


@dataclass(frozen=True)
class DegradeParams:
    """Everything ``tools/degrade_sequence.py`` needs (one typed object, validated on creation)."""

    mode: str = "dark"
    # low light
    gain: float = 0.15            # fraction of the recorded light that reaches the sensor
    full_well: float = 4000.0     # electrons at 8-bit white (effective, see module doc)
    read_noise: float = 4.0       # electrons rms
    gamma: float = 1.0            # encoding gamma of the stored values (1 = linear)
    # haze
    beta: float = 0.05            # extinction coefficient, 1/m (0.05: ~60 m visibility, fog)
    airlight: float = 220.0       # grey levels
    max_depth: float = 200.0      # m, given to pixels without a valid disparity
    num_disparities: int = 128    # SGBM search range (px), multiple of 16
    block_size: int = 5           # SGBM matching block (px), odd
    seed: int = 0

    def __post_init__(self):
        if self.mode not in DEGRADE_MODES:
            raise ConfigError("DegradeParams.mode", f"must be one of {', '.join(DEGRADE_MODES)}, got {self.mode!r}")
        _check_darken(self.gain, self.full_well, self.read_noise, self.gamma)
        _check_haze(self.beta, self.airlight, self.gamma)
        _check_sgbm(self.max_depth, self.num_disparities, self.block_size)
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ConfigError("DegradeParams.seed", f"must be a non-negative integer, got {self.seed!r}")

    @property
    def dark(self) -> bool:
        """Whether the sensor model runs (low light, or noise alone at gain 1)."""
        return "dark" in self.mode or "noise" in self.mode

    @property
    def effective_gain(self) -> float:
        return self.gain if "dark" in self.mode else 1.0

    @property
    def label(self) -> str:
        """Short cell name, e.g. ``g0.06-b0.03-high`` (gain, β, noise sensor)."""
        noise = next((k for k, v in NOISE_LEVELS.items() if v == (self.full_well, self.read_noise)),
                     f"fw{self.full_well:g}rn{self.read_noise:g}")
        beta = self.beta if self.haze else 0.0
        return f"g{self.effective_gain:g}-b{beta:g}-{noise}"

    @property
    def haze(self) -> bool:
        return "haze" in self.mode


# -- validation -----------------------------------------------------------------

def _finite(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)):
        raise ConfigError(name, f"must be a finite number, got {value!r}")
    return float(value)


def _check_darken(gain, full_well, read_noise, gamma) -> None:
    if not _finite("gain", gain) > 0.0:
        raise ConfigError("gain", f"must be > 0 (fraction of the light that reaches the sensor), got {gain!r}")
    if not _finite("full_well", full_well) > 0.0:
        raise ConfigError("full_well", f"must be > 0 electrons, got {full_well!r}")
    if not _finite("read_noise", read_noise) >= 0.0:
        raise ConfigError("read_noise", f"must be >= 0 electrons rms, got {read_noise!r}")
    if not _finite("gamma", gamma) > 0.0:
        raise ConfigError("gamma", f"must be > 0, got {gamma!r}")


def _check_haze(beta, airlight, gamma) -> None:
    if not _finite("beta", beta) >= 0.0:
        raise ConfigError("beta", f"must be >= 0 (extinction coefficient, 1/m), got {beta!r}")
    if not 0.0 <= _finite("airlight", airlight) <= WHITE:
        raise ConfigError("airlight", f"must be in [0, 255] grey levels, got {airlight!r}")
    if not _finite("gamma", gamma) > 0.0:
        raise ConfigError("gamma", f"must be > 0, got {gamma!r}")


def _check_sgbm(max_depth, num_disparities, block_size) -> None:
    if not _finite("max_depth", max_depth) > 0.0:
        raise ConfigError("max_depth", f"must be > 0 m, got {max_depth!r}")
    if isinstance(num_disparities, bool) or not isinstance(num_disparities, (int, np.integer)) \
            or num_disparities < 16 or num_disparities % 16:
        raise ConfigError("num_disparities", f"must be a positive multiple of 16, got {num_disparities!r}")
    if isinstance(block_size, bool) or not isinstance(block_size, (int, np.integer)) \
            or block_size < 1 or block_size % 2 == 0:
        raise ConfigError("block_size", f"must be a positive odd integer, got {block_size!r}")


def _check_image(image, name: str = "image") -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise InputError(name, f"expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise InputError(name, f"expected uint8 pixels, got {image.dtype}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)) or image.size == 0:
        raise InputError(name, f"expected a non-empty (H, W) or (H, W, C) image, got shape {image.shape}")
    return image


def _rng(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, bool) or not isinstance(rng, (int, np.integer)) or rng < 0:
        raise ConfigError("rng", f"must be a numpy Generator or a non-negative integer seed, got {rng!r}")
    return np.random.default_rng(int(rng))


# -- radiance <-> grey levels ----------------------------------------------------

def to_radiance(image: np.ndarray, gamma: float = 1.0) -> np.ndarray:
    """uint8 grey levels -> linear radiance in [0, 1] (float64)."""
    x = image.astype(np.float64) / WHITE
    return x if gamma == 1.0 else np.power(x, gamma)


def to_grey_levels(radiance: np.ndarray, gamma: float = 1.0) -> np.ndarray:
    """Linear radiance (clipped to [0, 1]) -> uint8 grey levels, rounded to nearest."""
    x = np.clip(radiance, 0.0, 1.0)
    if gamma != 1.0:
        x = np.power(x, 1.0 / gamma)
    return np.rint(x * WHITE).astype(np.uint8)


# -- low light --------------------------------------------------------------------

def darken(image: np.ndarray, gain: float, full_well: float = 4000.0, read_noise: float = 4.0,
           gamma: float = 1.0, rng: np.random.Generator | int = 0) -> np.ndarray:
    """Low-light exposure of ``image``: radiance × ``gain``, shot + read noise, 8-bit quantisation.

    ``rng``: a Generator (the caller owns the stream) or an integer seed
    (same seed, same output). ``gain`` > 1 brightens and saturates at white.
    """
    image = _check_image(image)
    _check_darken(gain, full_well, read_noise, gamma)
    gen = _rng(rng)
    electrons = gen.poisson(to_radiance(image, gamma) * (float(gain) * float(full_well))).astype(np.float64)
    if read_noise > 0:
        electrons += gen.normal(0.0, float(read_noise), size=image.shape)
    return to_grey_levels(electrons / float(full_well), gamma)


# -- haze ---------------------------------------------------------------------------

def transmission(depth_m, beta: float) -> np.ndarray:
    """t = exp(−β·d) (float64); β = 0 gives exactly 1 even at infinite depth."""
    _finite("beta", beta)
    d = np.asarray(depth_m, dtype=np.float64)
    if np.any(np.isnan(d)) or np.any(d < 0):
        raise InputError("depth", "depth must be >= 0 and not NaN (use a large value for 'far')")
    if beta == 0.0:
        return np.ones_like(d)
    return np.exp(-float(beta) * d)


def add_haze(image: np.ndarray, depth_m, beta: float, airlight: float = 220.0,
             gamma: float = 1.0) -> np.ndarray:
    """I = J·t + A·(1 − t), t = exp(−β·depth) (AGRI Eq. 1, Koschmieder's law).

    ``depth_m``: a scalar or an (H, W) array of ray lengths in metres (exact
    depth from a renderer, or ``ray_length(depth_from_stereo(...))``).
    ``airlight``: A in grey levels (all channels).
    """
    image = _check_image(image)
    _check_haze(beta, airlight, gamma)
    d = np.asarray(depth_m, dtype=np.float64)
    if d.ndim != 0 and d.shape != image.shape[:2]:
        raise InputError("depth", f"depth map is {d.shape} but the image is {image.shape[:2]}")
    t = transmission(d, beta)
    if image.ndim == 3 and t.ndim == 2:
        t = t[:, :, None]
    J = to_radiance(image, gamma)
    A = (float(airlight) / WHITE) ** gamma
    return to_grey_levels(J * t + A * (1.0 - t), gamma)


# -- depth from a rectified stereo pair -----------------------------------------------

def _grey(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(image[:, :, :3], cv2.COLOR_BGR2GRAY)
    return image


def disparity_sgbm(left: np.ndarray, right: np.ndarray, num_disparities: int = 128,
                   block_size: int = 5, paths: int = 5) -> np.ndarray:
    """Left-view disparity (float32 px) of a rectified pair by SGBM; invalid pixels are ≤ 0.

    ``paths``: 5 (OpenCV's 3-way mode) or 8 (``MODE_HH``, Hirschmüller's full 8 paths: less streaking
    along rows in low texture, the haze depth of ``depth_for_haze``)."""
    left, right = _check_image(left, "left"), _check_image(right, "right")
    if left.shape[:2] != right.shape[:2]:
        raise InputError("right", f"right image is {right.shape[:2]} but left is {left.shape[:2]}")
    _check_sgbm(1.0, num_disparities, block_size)
    channels = 1
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=int(num_disparities), blockSize=int(block_size),
        P1=8 * channels * block_size ** 2, P2=32 * channels * block_size ** 2,  # OpenCV's recommended smoothness
        disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_HH if paths == 8 else cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    raw = sgbm.compute(_grey(left), _grey(right))  # int16, disparity × 16
    return raw.astype(np.float32) / 16.0


def depth_from_stereo(left: np.ndarray, right: np.ndarray, calib: StereoCalibration,
                      max_depth: float = 200.0, num_disparities: int = 128, block_size: int = 5,
                      view: str = "left", fill: bool = True) -> np.ndarray:
    """Z-depth (float32 m) of the ``view`` camera from a rectified pair: bf / disparity.

    With ``fill``, holes in the disparity map are filled first
    (``fill_disparity_background``); what stays invalid, and depths beyond
    ``max_depth``, become ``max_depth``.
    """
    _check_sgbm(max_depth, num_disparities, block_size)
    disp = view_disparity(left, right, view, num_disparities, block_size)
    if fill:
        disp = fill_disparity_background(disp)
    return _depth_from_disparity(disp, calib, max_depth)


def view_disparity(left: np.ndarray, right: np.ndarray, view: str, num_disparities: int = 128,
                   block_size: int = 5, paths: int = 5) -> np.ndarray:
    """SGBM disparity (``disparity_sgbm``) of the ``view`` camera ("left" or "right") of a rectified pair."""
    if view == "left":
        return disparity_sgbm(left, right, num_disparities, block_size, paths)
    if view == "right":
        # Mirror both images: the right view becomes a left reference looking at a
        # mirrored left image, with the same (positive) disparities.
        return disparity_sgbm(np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1]),
                              num_disparities, block_size, paths)[:, ::-1]
    raise ConfigError("view", f"must be 'left' or 'right', got {view!r}")


def _depth_from_disparity(disp: np.ndarray, calib: StereoCalibration, max_depth: float) -> np.ndarray:
    """bf / disparity (float32 m); invalid (≤ 0) disparities and depths beyond ``max_depth`` are ``max_depth``."""
    with np.errstate(divide="ignore"):
        depth = np.where(disp > 0, calib.bf / np.maximum(disp, 1e-6), np.inf)
    return np.minimum(depth, float(max_depth)).astype(np.float32)


def depth_from_rendered(depth_left: np.ndarray, calib: StereoCalibration, max_depth: float = 200.0,
                        view: str = "left") -> np.ndarray:
    """Z-depth (float32 m) of the ``view`` camera from the left camera's exact rendered depth.

    For generated sequences, whose renderer writes the left depth (``mav0/depth0``, 0 = sky): SGBM on
    a *dark* clean pair (dark-rows, mean grey ~11) returns blocky depth with holes that differs
    between the cameras, and haze painted with it is texture at the wrong disparity (s8-haze notes).
    The right view is the left depth forward-warped by its disparity bf / z (the nearest surface
    wins a pixel), its occlusion holes filled with the farther neighbour
    (``fill_disparity_background``); sky and depths beyond ``max_depth`` become ``max_depth``, as
    ``depth_from_stereo`` gives pixels without a disparity.
    """
    z = np.asarray(depth_left, dtype=np.float64)
    if z.ndim != 2 or z.shape != (calib.height, calib.width):
        raise InputError("depth_left", f"must be a {calib.height}x{calib.width} depth map, got shape {z.shape}")
    z = np.where(z > 0, np.minimum(z, float(max_depth)), float(max_depth))  # sky (0) is far, not missing
    disp = calib.bf / z
    if view == "right":
        h, w = z.shape
        u_r = np.rint(np.arange(w)[None, :] - disp).astype(np.int64)
        hit = (u_r >= 0) & (u_r < w)
        rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
        warped = np.zeros((h, w))
        np.maximum.at(warped, (rows[hit], u_r[hit]), disp[hit])  # the nearest surface (largest d) wins
        disp = fill_disparity_background(warped)
    elif view != "left":
        raise ConfigError("view", f"must be 'left' or 'right', got {view!r}")
    with np.errstate(divide="ignore"):
        depth = np.where(disp > 0, calib.bf / np.maximum(disp, 1e-6), np.inf)
    return np.minimum(depth, float(max_depth)).astype(np.float32)


def fill_disparity_background(disp: np.ndarray) -> np.ndarray:
    """Fill invalid (≤ 0) disparities row by row with the smaller of the nearest valid ones.

    The KITTI stereo devkit's background interpolation: a hole between two
    valid pixels takes the smaller disparity (the farther surface: holes are
    mostly occlusions of the background), a hole at a row end takes its one
    neighbour; rows without any valid pixel stay invalid. Vectorised.
    """
    disp = np.asarray(disp, dtype=np.float32)
    h, w = disp.shape
    valid = disp > 0
    cols = np.broadcast_to(np.arange(w), (h, w))
    left = np.maximum.accumulate(np.where(valid, cols, -1), axis=1)
    right = np.minimum.accumulate(np.where(valid, cols, w)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    has_l, has_r = left >= 0, right < w
    d_l = np.where(has_l, disp[rows, np.clip(left, 0, w - 1)], np.inf)
    d_r = np.where(has_r, disp[rows, np.clip(right, 0, w - 1)], np.inf)
    filled = np.minimum(d_l, d_r)
    return np.where(valid, disp, np.where(np.isfinite(filled), filled, 0.0)).astype(np.float32)


def texture_mask(image: np.ndarray, min_std: float, window: int = 7) -> np.ndarray:
    """Pixels whose ``window``² neighbourhood has a grey-level std ≥ ``min_std``: where SGBM's disparity
    is a measurement and not the smoothness term's guess (textureless sky, flat airlight)."""
    f = _grey(image).astype(np.float32)
    m, m2 = cv2.blur(f, (window, window)), cv2.blur(f * f, (window, window))
    return np.sqrt(np.maximum(m2 - m * m, 0.0)) >= float(min_std)


def _nearest_valid(disp: np.ndarray, valid: np.ndarray, axis: int):
    """Per pixel, the disparity of the nearest valid pixel before and after it along ``axis`` (inf if
    none), and whether one exists before it."""
    n = disp.shape[axis]
    idx = np.broadcast_to(np.arange(n).reshape((-1, 1) if axis == 0 else (1, -1)), disp.shape)
    before = np.maximum.accumulate(np.where(valid, idx, -1), axis=axis)
    after = np.flip(np.minimum.accumulate(np.flip(np.where(valid, idx, n), axis), axis=axis), axis)
    take = lambda i: np.take_along_axis(disp, np.clip(i, 0, n - 1), axis)  # noqa: E731
    return np.where(before >= 0, take(before), np.inf), np.where(after < n, take(after), np.inf), before >= 0


def fill_disparity_sky(disp: np.ndarray) -> np.ndarray:
    """Fill invalid (≤ 0) disparities with the smallest (farthest) of the nearest valid ones in the
    row *and* the column; a hole with no valid pixel above it in a column that has one is sky (0:
    far). The KITTI devkit's background rule (``fill_disparity_background``) in two dimensions: a
    strip under a tree's crown between two trunks is bounded by near surfaces in its row but by the
    far ground below. The sky rule assumes an upright outdoor camera (KITTI), not a room (EuRoC).
    Columns without any valid pixel (SGBM's left border strip) take the row rule alone."""
    disp = np.asarray(disp, dtype=np.float32)
    valid = disp > 0
    left, right, _ = _nearest_valid(disp, valid, 1)
    up, down, has_up = _nearest_valid(disp, valid, 0)
    col_any = valid.any(axis=0)[None, :]
    up, down = np.where(col_any, up, np.inf), np.where(col_any, down, np.inf)
    filled = np.minimum(np.minimum(left, right), np.minimum(up, down))
    filled = np.where(np.isfinite(filled), filled, 0.0)
    sky = ~has_up & col_any
    return np.where(valid, disp, np.where(sky, 0.0, filled)).astype(np.float32)


# Texture (grey-level std in 7x7) below which SGBM's disparity is not kept for the haze depth. Chosen
# on the generated presets' exact-depth haze (benchmarks/haze_depth_error.py; docs/notes/s22-hazepaint.md):
# 1.5 gave the smallest painted-haze error near depth edges (3, which also clears KITTI's noisy sky,
# costs the presets' dark ground).
HAZE_MIN_TEXTURE = 1.5


def depth_for_haze(left: np.ndarray, right: np.ndarray, calib: StereoCalibration, max_depth: float = 200.0,
                   num_disparities: int = 128, block_size: int = 5, view: str = "left",
                   min_texture: float = HAZE_MIN_TEXTURE) -> np.ndarray:
    """Z-depth (float32 m) for painting haze on a real outdoor pair (``--haze-depth stereo-sky``).

    ``depth_from_stereo`` keeps every SGBM disparity and fills holes along rows. On the generated
    presets, against the haze painted from the renderer's exact depth, that paints far surfaces and
    sky with near depth (too little airlight: −23 to −82 grey levels on average beyond 40 m at β 0.06):
    SGBM "measures" textureless sky by its smoothness term, and row fills under tree crowns take the
    trunks' depth. Here: SGBM with 8 paths, disparities kept only where the image has texture
    (``texture_mask``), holes filled by ``fill_disparity_sky``; beyond ``max_depth`` is ``max_depth``.
    """
    _check_sgbm(max_depth, num_disparities, block_size)
    disp = view_disparity(left, right, view, num_disparities, block_size, paths=8)
    ref = left if view == "left" else right
    return _depth_from_disparity(fill_disparity_sky(np.where(texture_mask(ref, min_texture), disp, 0.0)),
                                 calib, max_depth)


def ray_length(depth_z: np.ndarray, calib: StereoCalibration) -> np.ndarray:
    """Distance along each pixel's ray (m) from its z-depth in the rectified camera."""
    h, w = depth_z.shape
    x = (np.arange(w, dtype=np.float64) - calib.cx) / calib.fx
    y = (np.arange(h, dtype=np.float64) - calib.cy) / calib.fy
    scale = np.sqrt(1.0 + x[None, :] ** 2 + y[:, None] ** 2)
    return (depth_z * scale).astype(np.float32)


def degrade_image(image: np.ndarray, params: DegradeParams, ray_m=None,
                  rng: np.random.Generator | int = 0) -> np.ndarray:
    """Apply ``params.mode`` to one image: haze (needs ``ray_m``), then low light."""
    out = image
    if params.haze:
        if ray_m is None:
            raise ConfigError("mode", f"mode {params.mode!r} needs a depth map for the haze")
        out = add_haze(out, ray_m, params.beta, params.airlight, params.gamma)
    if params.dark:
        out = darken(out, params.effective_gain, params.full_well, params.read_noise, params.gamma, rng)
    return out


def grid_cells(gains=GRID_GAINS, betas=GRID_BETAS, noise_levels=tuple(NOISE_LEVELS), seed: int = 0,
               **common) -> list[DegradeParams]:
    """The degradation grid: one ``DegradeParams`` per (gain, β, noise level).

    Gain 1 with β 0 is the sensor noise alone (mode ``noise``); every cell has
    shot and read noise of its noise level. ``common``: other DegradeParams
    fields (airlight, max_depth, ...).
    """
    cells = []
    for noise in noise_levels:
        if noise not in NOISE_LEVELS:
            raise ConfigError("noise_levels", f"unknown noise level {noise!r}; known: {', '.join(NOISE_LEVELS)}")
        full_well, read_noise = NOISE_LEVELS[noise]
        for gain in gains:
            for beta in betas:
                dark = "dark" if gain != 1.0 else "noise"
                mode = dark if beta == 0 else ("dark+haze" if dark == "dark" else "haze+noise")
                cells.append(DegradeParams(mode=mode, gain=float(gain), beta=float(beta), full_well=full_well,
                                           read_noise=read_noise, seed=seed, **common))
    return cells
