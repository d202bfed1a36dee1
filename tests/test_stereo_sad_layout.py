"""The centre-normalised SAD of the stereo refinement (``stereo._centre_sad``, keypoints on the
innermost axis) equals a written-out per-keypoint reference: Σ|(R − R_c) − (L − L_c)| for every
shift, and ``subpixel_refine`` built on it gives what the (K,P,P)-layout loop gave (issue 8,
docs/notes/s15-trackcpu.md)."""
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from canopy.frontend import stereo


def _reference_sad(patch_l: np.ndarray, band: np.ndarray, n_shifts: int) -> np.ndarray:
    """Per keypoint and shift, in int64: the definition, no layout tricks."""
    k, P = patch_l.shape[0], patch_l.shape[1]
    w = P // 2
    out = np.empty((k, n_shifts))
    for i in range(k):
        pl = patch_l[i].astype(np.int64) - int(patch_l[i, w, w])
        for s in range(n_shifts):
            win = band[i, :, s:s + P].astype(np.int64)
            out[i, s] = np.abs((win - int(win[w, w])) - pl).sum()
    return out


def _loop_in_kpp_layout(patch_l, band, n_shifts):
    """The loop this replaced (main 90c31e7): (K,P,P) layout, one shift at a time, uint16 sums."""
    w = patch_l.shape[1] // 2
    P = patch_l.shape[1]
    pl = patch_l.astype(np.int16)
    bd = band.astype(np.int16)
    pl -= pl[:, w:w + 1, w:w + 1]
    sad = np.empty((len(pl), n_shifts))
    diff = np.empty(pl.shape, np.int16)
    for shift in range(n_shifts):
        np.subtract(bd[:, :, shift:shift + P], pl, out=diff)
        diff -= bd[:, w:w + 1, shift + w:shift + w + 1]
        np.abs(diff, out=diff)
        sad[:, shift] = diff.reshape(len(pl), -1).view(np.uint16).sum(axis=1, dtype=np.uint16)
    return sad


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("w,L", [(5, 5), (3, 2), (6, 4)])
def test_centre_sad_equals_the_definition(seed, w, L):
    rng = np.random.default_rng(seed)
    P, S = 2 * w + 1, 2 * L + 1
    k = 57
    # extreme pixels included: 0 / 255 patches against 255 / 0 bands reach |difference| 510
    patch = rng.integers(0, 256, (k, P, P), dtype=np.uint8)
    band = rng.integers(0, 256, (k, P, P + S - 1), dtype=np.uint8)
    patch[0], band[0] = 0, 255
    patch[1], band[1] = 255, 0
    patch[2, w, w], band[2] = 255, 0
    sum_type = np.uint16 if P * P * 510 < 1 << 16 else np.int32
    got = stereo._centre_sad(patch, band, S, sum_type)
    assert got.shape == (k, S) and got.dtype == np.float64
    assert np.array_equal(got, _reference_sad(patch, band, S))
    if sum_type == np.uint16:
        assert np.array_equal(got, _loop_in_kpp_layout(patch, band, S))


def test_centre_sad_of_no_keypoints_is_empty():
    got = stereo._centre_sad(np.zeros((0, 11, 11), np.uint8), np.zeros((0, 11, 21), np.uint8), 11, np.uint16)
    assert got.shape == (0, 11)


def test_subpixel_refine_unchanged_on_textured_images():
    """The whole refinement, against the same function with the (K,P,P) loop put back."""
    rng = np.random.default_rng(7)
    base = rng.integers(0, 256, (120, 400), dtype=np.uint8)
    left = base
    right = np.roll(base, -9, axis=1)  # 9 px disparity
    right = np.clip(right.astype(int) + rng.integers(-6, 7, right.shape), 0, 255).astype(np.uint8)
    n = 300
    uvl = np.column_stack([rng.uniform(30, 370, n), rng.uniform(10, 110, n)])
    ur = uvl[:, 0] - 9 + rng.integers(-3, 4, n)
    octave = rng.integers(0, 3, n)
    sf = 1.2 ** np.arange(8)
    got = stereo.subpixel_refine(left, right, uvl, ur, octave, sf, 5, 5)

    orig = stereo._centre_sad
    try:
        stereo._centre_sad = lambda p, b, s, t: _loop_in_kpp_layout(p, b, s)
        want = stereo.subpixel_refine(left, right, uvl, ur, octave, sf, 5, 5)
    finally:
        stereo._centre_sad = orig
    assert got[2].sum() > 100  # most keypoints refine
    for g, x in zip(got, want):
        assert g.dtype == x.dtype and np.array_equal(g, x)


@pytest.mark.parametrize("shape", [(40, 60), (11, 21), (30, 25)])
def test_windows_is_sliding_window_view(shape):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, shape, dtype=np.uint8)
    for view in (img, img[:, ::2], img[1:, 2:]):          # contiguous and strided images
        if view.shape[0] < 11 or view.shape[1] < 11:
            continue
        for rows, cols in ((11, 11), (11, min(21, view.shape[1]))):
            got, want = stereo._windows(view, rows, cols), sliding_window_view(view, (rows, cols))
            assert got.shape == want.shape and got.strides == want.strides and not got.flags.writeable
            assert np.array_equal(got, want)
