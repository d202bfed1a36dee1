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


def _reference_subpixel_refine(left_img, right_img, uvl, ur, octave, scale_factors, w, L, normalise):
    """main 90c31e7's ``subpixel_refine`` written out (one pass per level, (K,P,P) layout)."""
    k = len(uvl)
    u_out, sad_out, ok_out = np.full(k, -1.0), np.full(k, np.inf), np.zeros(k, bool)
    levels = np.unique(octave)
    pyr_l = stereo.image_pyramid(left_img, scale_factors, levels)
    pyr_r = stereo.image_pyramid(right_img, scale_factors, levels)
    parts = []
    for lvl in levels:
        sel = np.flatnonzero(octave == lvl)
        s = scale_factors[lvl]
        il, ir = pyr_l[int(lvl)], pyr_r[int(lvl)]
        hh, ww = il.shape
        xl = np.round(uvl[sel, 0] / s).astype(np.int64)
        yl = np.round(uvl[sel, 1] / s).astype(np.int64)
        xr0 = np.round(ur[sel] / s).astype(np.int64)
        inside = ((yl - w >= 0) & (yl + w < hh) & (xl - w >= 0) & (xl + w < ww)
                  & (xr0 - L - w >= 0) & (xr0 + L + w < ww))
        sel, xl, yl, xr0 = sel[inside], xl[inside], yl[inside], xr0[inside]
        if len(sel) == 0:
            continue
        patch_l = sliding_window_view(il, (2 * w + 1, 2 * w + 1))[yl - w, xl - w]
        band = sliding_window_view(ir, (2 * w + 1, 2 * (L + w) + 1))[yl - w, xr0 - L - w]
        parts.append((sel, xr0, np.full(len(sel), s), patch_l, band))
    if not parts:
        return u_out, sad_out, ok_out
    sel, xr0, s = (np.concatenate([part[i] for part in parts]) for i in range(3))
    patch_l = np.concatenate([part[3] for part in parts])
    band = np.concatenate([part[4] for part in parts])
    if normalise == "mean":
        sad = stereo._zero_mean_sad(patch_l.astype(np.int16), band.astype(np.int16), 2 * L + 1)
    else:
        sad = _loop_in_kpp_layout(patch_l, band, 2 * L + 1)
    best, delta, best_sad, good = stereo.parabola_minimum(sad, L)
    u_out[sel] = s * (xr0 + (best - L) + delta)
    sad_out[sel] = best_sad
    ok_out[sel] = good
    return u_out, sad_out, ok_out


@pytest.mark.parametrize("normalise", ["centre", "mean"])
@pytest.mark.parametrize("octave_dtype", [np.int64, np.int32, np.int8])
def test_subpixel_refine_equals_the_per_level_reference(normalise, octave_dtype):
    """Keypoints on 4 levels (one level empty, one only near the border), some windows off the
    image: the level-sorted refinement gives the per-level loop's outputs bit for bit."""
    rng = np.random.default_rng(7)
    base = rng.integers(0, 256, (120, 400), dtype=np.uint8)
    left = base
    right = np.roll(base, -9, axis=1)  # 9 px disparity
    right = np.clip(right.astype(int) + rng.integers(-6, 7, right.shape), 0, 255).astype(np.uint8)
    n = 400
    uvl = np.column_stack([rng.uniform(0, 400, n), rng.uniform(0, 120, n)])   # some off the windows
    ur = uvl[:, 0] - 9 + rng.integers(-3, 4, n)
    octave = rng.choice([0, 1, 3, 5], n).astype(octave_dtype)
    octave[uvl[:, 1] > 30] = np.where(octave[uvl[:, 1] > 30] == 5, 1, octave[uvl[:, 1] > 30])  # level 5: top rows only
    sf = 1.2 ** np.arange(8)
    got = stereo.subpixel_refine(left, right, uvl, ur, octave, sf, 5, 5, normalise)
    want = _reference_subpixel_refine(left, right, uvl, ur, octave, sf, 5, 5, normalise)
    assert got[2].sum() > 100 and (~np.isfinite(got[1])).sum() > 10  # most refine, some off the image
    for g, x in zip(got, want):
        assert g.dtype == x.dtype and np.array_equal(g, x)
    # with the pair's pyramids built ahead (the tracker's worker)
    pyr = stereo.PairPyramids.build(left, right, sf)
    got = stereo.subpixel_refine(left, right, uvl, ur, octave, sf, 5, 5, normalise, pyramids=pyr)
    for g, x in zip(got, want):
        assert g.dtype == x.dtype and np.array_equal(g, x)


def test_subpixel_refine_with_every_window_off_the_image():
    img = np.zeros((30, 40), np.uint8)
    got = stereo.subpixel_refine(img, img, np.array([[1.0, 1.0], [39.0, 29.0]]), np.array([0.5, 38.0]),
                                 np.array([0, 1]), 1.2 ** np.arange(8), 5, 5)
    assert np.array_equal(got[0], [-1.0, -1.0]) and np.all(np.isinf(got[1])) and not got[2].any()


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


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_column_range_is_min_max_over_axis_0(dtype):
    from canopy.frontend.matching import _column_range
    rng = np.random.default_rng(5)
    for n in (1, 2, 7, 2000):
        uv = (rng.standard_normal((n, 2)) * 300).astype(dtype)
        lo, hi = _column_range(uv)
        for got, want in ((lo, uv.min(axis=0)), (hi, uv.max(axis=0))):
            assert got.dtype == want.dtype and np.array_equal(got, want)
    uv = np.array([[1.0, 2.0], [np.nan, 0.5], [3.0, 4.0]], dtype)
    lo, hi = _column_range(uv)
    assert np.isnan(lo[0]) and np.isnan(hi[0]) and lo[1] == 0.5 and hi[1] == 4.0
