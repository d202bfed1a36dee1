"""The flow-based recursive temporal filter of benchmarks/temporal_flow_filter.py (s22, an experiment, not shipped):
noise falls on a moving textured scene, a moving object leaves no ghost, the first frame passes unchanged."""
import importlib.util
import sys
from pathlib import Path

import cv2
import numpy as np

_BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(_BENCH))
_spec = importlib.util.spec_from_file_location("temporal_flow_filter", _BENCH / "temporal_flow_filter.py")
tf = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tf)

H, W, SIGMA = 240, 320, 8.0


def _texture(seed=1) -> np.ndarray:
    """A band-limited random texture (blurred noise, contrast ~40 grey levels) bigger than the frame."""
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.normal(0, 1, (H + 80, W + 80)).astype(np.float32), (0, 0), 2.0)
    return 128.0 + 40.0 * t / t.std()


def _frame(tex, dx: float, square_x=None) -> np.ndarray:
    """The texture panned by ``dx`` px (sub-pixel, bilinear) and, optionally, a bright 30 px square at ``square_x``."""
    M = np.float32([[1, 0, 40 + dx], [0, 1, 40]])
    img = cv2.warpAffine(tex, M, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    if square_x is not None:
        img[100:130, square_x:square_x + 30] = 250.0
    return img


def _noisy(img, rng) -> np.ndarray:
    return np.clip(np.rint(img + rng.normal(0, SIGMA, img.shape)), 0, 255).astype(np.uint8)


def test_first_frame_unchanged_and_noise_falls_on_a_panning_scene():
    tex, rng = _texture(), np.random.default_rng(0)
    f = tf.TemporalFilter(weight=0.6, k=2.0, downsample=2)
    first = _noisy(_frame(tex, 0.0), rng)
    np.testing.assert_array_equal(f.filter(first, SIGMA), first)
    for i in range(1, 10):
        truth = _frame(tex, 1.3 * i)
        noisy = _noisy(truth, rng)
        out = f.filter(noisy, SIGMA)
    inner = (slice(20, H - 20), slice(20, W - 20))
    err_in = np.sqrt(np.mean((noisy[inner] - truth[inner]) ** 2))
    err_out = np.sqrt(np.mean((out[inner] - truth[inner]) ** 2))
    assert err_in > 0.9 * SIGMA
    assert err_out < 0.75 * err_in, (err_out, err_in)


def test_a_moving_square_leaves_no_ghost():
    tex, rng = _texture(2), np.random.default_rng(3)
    f = tf.TemporalFilter(weight=0.6, k=2.0, downsample=2)
    for i in range(8):  # the background still, a bright square moving 12 px a frame
        truth = _frame(tex, 0.0, square_x=60 + 12 * i)
        out = f.filter(_noisy(truth, rng), SIGMA)
    behind = (slice(100, 130), slice(60 + 12 * 6 - 24, 60 + 12 * 6 + 12))  # where the square was 1–2 frames ago
    square = (slice(102, 128), slice(60 + 12 * 7 + 2, 60 + 12 * 7 + 28))
    # no trail of the square's 250 on the background, and the square itself is not dimmed by the past
    assert np.abs(out[behind].astype(float) - truth[behind]).mean() < 2.0 * SIGMA
    assert out[square].mean() > 235.0


def test_reset_forgets_the_past():
    tex, rng = _texture(), np.random.default_rng(5)
    f = tf.TemporalFilter()
    f.filter(_noisy(_frame(tex, 0.0), rng), SIGMA)
    f.reset()
    again = _noisy(_frame(tex, 1.0), rng)
    np.testing.assert_array_equal(f.filter(again, SIGMA), again)
