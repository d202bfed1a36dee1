"""Stereo matching on rectified images (AGRI §3.2.2), after ORB-SLAM2's ComputeStereoMatches.

For every left keypoint: right keypoints on the same row band (± row_tolerance scaled by
the octave), with a neighbouring octave and a disparity in [min, max]; best Hamming
distance with a ratio test to the second best; each right keypoint used once; then
sub-pixel refinement of u_right by SAD patch correlation along the row on the keypoint's
pyramid level with a parabola fit through the three costs around the minimum; finally
matches whose SAD exceeds ``sad_outlier_factor`` times the median are rejected. A calibrated
constant disparity offset (``disparity_offset_px``, or ``disparity_offset_cells_px`` for keypoints of
the cells extractor) is added to every disparity.

Zero-mean SAD on hazy / noisy frames (``subpixel_mean_on_fill``, s21): ORB-SLAM2's SAD subtracts each
patch's centre pixel, whose noise (σ√2 between the two patches) then shifts all 121 differences alike;
where haze halves the contrast, or the sensor noise is 12 grey levels after an enhancement, that shift
is as large as the texture the SAD compares and the minimum jumps by whole pixels. Measured against the
renderer's exact depth (dusk-loop g0.3-b0.03-high, seed 11, 300 frames, the tracker's own matches):
5.8 % of the stereo matches > 2 px off (clean 0.1 %), and no long bias at the median (depth -0.14 %);
the "landmarks too far" are the heavy tail through bf / d (mean depth +0.20 %). Subtracting the patch
mean instead (its noise is σ / 11) leaves 0.2 % > 2 px. The parabola fit, the octave and the offset
are not the cause: the signed error is within ±0.05 px at every octave but 4 (+0.1 px there, on the
clean pair too). The switch uses the fill-in's gate (``stereo_fill.fill_active``: low texture against
the noise, or the enhancement's noise sigma), so frames outside it, clean KITTI / EuRoC / the clean
presets, keep ORB-SLAM2's centre SAD and their disparity offsets calibrated with it. s21 left it off: the
per-match depth is 3x better on every gated cell, the trajectories better or worse by noise draw
(docs/notes/s21-hazedepth.md). On in configs/kitti.yaml since s23: on KITTI's lit hazy low-noise cells the
centre SAD leaves the path 0.17-0.45 % short and the mean brings the scale closer to 1 on all 5 draws
measured (ATE better on 6 of 8 cell-draws, mean 63.4 -> 44.4 mm; docs/notes/s23-lead.md).
``subpixel_mean_on_noisy_haze`` (s24; on in configs/kitti.yaml) opens it on the hazy frames of a noisy sensor too, whose pair the
refinement smooths (``stereo_fill.mean_on_noisy_haze``; docs/notes/s24-kittinoisy.md).
All steps are batched numpy (candidate pairs via row bands, one loop over pyramid levels).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.lib.stride_tricks import as_strided

from canopy.frontend.features import Features
from canopy.frontend.matching import as_words, best_two, hamming_pairs, unique_by_reference
from canopy.frontend.noisy_features import accept_sad, refinement_pair
from canopy.frontend.params import TrackingParams
from shared.types import StereoCalibration


@dataclass
class StereoMatches:
    """Per left keypoint: refined right-image column and depth, -1 where unmatched."""

    u_right: np.ndarray  # (N,) float32
    depth: np.ndarray    # (N,) float32
    n_candidates: int = 0
    # True where the keypoint sits on an occluding contour (canopy.frontend.stereo_silhouette):
    # its disparity is no 3D point's; None: not tested (tracking.contour_enabled off)
    on_contour: np.ndarray | None = None

    @property
    def valid(self) -> np.ndarray:
        return self.depth > 0


def image_pyramid(image: np.ndarray, scale_factors: np.ndarray, levels: np.ndarray) -> dict[int, np.ndarray]:
    """Resized images for the requested levels (level 0 is the image itself)."""
    h, w = image.shape[:2]
    out = {}
    for lvl in levels:
        s = scale_factors[lvl]
        out[int(lvl)] = image if lvl == 0 else cv2.resize(
            image, (int(round(w / s)), int(round(h / s))), interpolation=cv2.INTER_LINEAR)
    return out


@dataclass
class PairPyramids:
    """``image_pyramid`` of both images of a pair, every level, built ahead of the matching: the
    tracker's stereo worker builds them while it waits for the left keypoints (they need only the
    images), so ~3 ms of the matching leave the path the tracking thread waits on. They serve a
    ``subpixel_refine`` call only for the very image objects they were built from."""

    left_img: np.ndarray
    right_img: np.ndarray
    left: dict[int, np.ndarray]
    right: dict[int, np.ndarray]

    @classmethod
    def build(cls, left_img: np.ndarray, right_img: np.ndarray, scale_factors: np.ndarray) -> "PairPyramids":
        levels = np.arange(len(scale_factors))
        return cls(left_img, right_img, image_pyramid(left_img, scale_factors, levels),
                   image_pyramid(right_img, scale_factors, levels))

    def serves(self, left_img: np.ndarray, right_img: np.ndarray) -> bool:
        return self.left_img is left_img and self.right_img is right_img


def subpixel_refine(left_img: np.ndarray, right_img: np.ndarray, uvl: np.ndarray, ur: np.ndarray,
                    octave: np.ndarray, scale_factors: np.ndarray, half_window: int, search: int,
                    normalise: str = "centre", pyramids: PairPyramids | None = None):
    """SAD correlation of an (2w+1)^2 patch along the row, parabola fit of the minimum.

    Returns refined u_right (level-0 px), the SAD at the minimum and a validity mask.
    ``normalise`` says what is subtracted from each patch before the SAD (both are illumination
    normalisations): "centre", its centre pixel (ORB-SLAM2's ComputeStereoMatches), or "mean",
    its mean (zero-mean SAD). The centre pixel carries the full sensor noise σ and shifts all
    (2w+1)² differences by it, which on low-contrast (hazy) patches is as large as the texture the
    SAD compares; the mean has σ / (2w+1). KITTI 06, stereo matches > 1 px off the clean SGBM
    disparity: clean 10–19 % (centre) vs 6–10 % (mean); haze β 0.06 + noisy sensor 23–34 % vs
    12–20 % (docs/notes/s7-haze.md).
    ``pyramids``: both images' levels if built already (used only if built from these images).
    """
    if normalise not in ("centre", "mean"):
        raise ValueError(f"subpixel_refine: normalise must be 'centre' or 'mean' (got {normalise!r})")
    k = len(uvl)
    u_out = np.full(k, -1.0, np.float64)
    sad_out = np.full(k, np.inf)
    ok_out = np.zeros(k, bool)
    if k == 0:
        return u_out, sad_out, ok_out
    w, L = half_window, search
    levels = np.unique(octave)
    if pyramids is not None and pyramids.serves(left_img, right_img):
        pyr_l, pyr_r = pyramids.left, pyramids.right
    else:
        pyr_l = image_pyramid(left_img, scale_factors, levels)
        pyr_r = image_pyramid(right_img, scale_factors, levels)
    # |differences| are <= 510: a patch's SAD fits 16 bits unsigned up to 128 pixels (11x11), and
    # 16-bit sums run ~1.6x faster than 32-bit ones; larger windows sum in 32 bits
    sum_type = np.uint16 if (2 * w + 1) ** 2 * 510 < 1 << 16 else np.int32
    # patches of every level gathered first, then one SAD pass over all of them: each row's
    # arithmetic is the same, and one pass instead of one per level saves ~8x the numpy calls
    # the keypoints by level (a stable sort: within a level in index order, as one flatnonzero per
    # level gives them), their level coordinates and the window test in one pass each (the same
    # per-element divisions by the level's scale); per level only the two window gathers
    order = np.argsort(octave, kind="stable")
    oc = octave[order]
    s_all = scale_factors[oc]
    xl = np.round(uvl[order, 0] / s_all).astype(np.int64)
    yl = np.round(uvl[order, 1] / s_all).astype(np.int64)
    xr0 = np.round(ur[order] / s_all).astype(np.int64)
    at = np.searchsorted(levels, oc)
    hh, ww = (np.array([pyr_l[int(lvl)].shape[i] for lvl in levels], np.int64)[at] for i in (0, 1))
    inside = np.flatnonzero((yl - w >= 0) & (yl + w < hh) & (xl - w >= 0) & (xl + w < ww)
                            & (xr0 - L - w >= 0) & (xr0 + L + w < ww))
    if len(inside) == 0:
        return u_out, sad_out, ok_out
    sel, oc, s, xl, yl, xr0 = order[inside], oc[inside], s_all[inside], xl[inside], yl[inside], xr0[inside]
    kept = np.unique(oc)
    bounds = np.searchsorted(oc, kept).tolist() + [len(oc)]
    patches, bands = [], []
    for lvl, a, b in zip(kept.tolist(), bounds[:-1], bounds[1:]):
        # whole patch rows copied from sliding-window views (the same pixels as a gather of every
        # pixel by (row, column) index arrays, ~3x faster); uint8 until all levels are joined
        patches.append(_windows(pyr_l[lvl], 2 * w + 1, 2 * w + 1)[yl[a:b] - w, xl[a:b] - w])           # (K,P,P)
        bands.append(_windows(pyr_r[lvl], 2 * w + 1, 2 * (L + w) + 1)[yl[a:b] - w, xr0[a:b] - L - w])  # (K,P,2L+2w+1)
    if normalise == "mean":
        sad = _zero_mean_sad(np.concatenate(patches).astype(np.int16), np.concatenate(bands).astype(np.int16),
                             2 * L + 1)
    else:
        sad = _centre_sad(np.concatenate(patches), np.concatenate(bands), 2 * L + 1, sum_type)
    best, delta, best_sad, good = parabola_minimum(sad, L)
    u_out[sel] = s * (xr0 + (best - L) + delta)
    sad_out[sel] = best_sad
    ok_out[sel] = good
    return u_out, sad_out, ok_out


def raw_vertex(raw_pair: tuple[np.ndarray, np.ndarray], uvl: np.ndarray, ur: np.ndarray, ok: np.ndarray,
               octave: np.ndarray, scale_factors: np.ndarray, params: TrackingParams, normalise: str,
               pyramids: PairPyramids | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The sub-pixel vertex of the raw pair's SAD within ``subpixel_raw_vertex_search`` px (at the
    keypoint's level) of the smoothed pair's result ``ur``; kept where both searches found an interior
    minimum. Why: a Gaussian of 2 px before the SAD makes the search robust to the noise (the right
    whole pixel), but its vertex moves with what the blur mixes into the window: on KITTI's clean frames,
    against the raw pair's vertex, far points (d < 5 px) read +0.12..+0.15 px and 8-20 px ones
    -0.03..-0.065 px (blur 1 px: a third of that), the bands that set the path's scale. A horizontal shift
    commutes with the blur only for a window at one depth. Around the smoothed minimum the raw vertex keeps
    the robustness: with white noise σ 6 on KITTI 06, against the clean pair, the band means fall to
    |0.02| px (3-5 px: +0.04), their spread 0.44-0.66 -> 0.18-0.42 px and matches > 1 px off 12.7 -> 4.3 %,
    for 3 % fewer matches (docs/notes/s31-vertex.md)."""
    ur_raw, _, ok_raw = subpixel_refine(raw_pair[0], raw_pair[1], uvl, np.where(ok, ur, -1.0), octave,
                                        scale_factors, params.subpixel_window, params.subpixel_raw_vertex_search,
                                        normalise, pyramids)
    ok = ok & ok_raw
    return np.where(ok, ur_raw, ur), ok


def parabola_minimum(sad: np.ndarray, L: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per row of ``sad`` ((K, 2L+1) costs over the shifts -L..L): the best shift's index, the
    sub-pixel offset of the parabola through it and its two neighbours (ORB-SLAM2's ComputeStereoMatches),
    the best cost, and whether the offset is trusted (an interior minimum, |offset| <= 1)."""
    best = np.argmin(sad, axis=1)
    interior = (best > 0) & (best < 2 * L)
    idx = np.arange(len(sad))
    b = np.clip(best, 1, 2 * L - 1)
    d1, d2, d3 = sad[idx, b - 1], sad[idx, b], sad[idx, b + 1]
    denom = 2.0 * (d1 + d3 - 2.0 * d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(denom > 0, (d1 - d3) / denom, 0.0)
    delta = np.where(interior, delta, 0.0)  # no parabola at the window's edge (ORB-SLAM2: rejected)
    good = interior & (np.abs(delta) <= 1.0)
    return best, delta, sad[idx, best], good


def _windows(image: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Read-only view of every (rows, cols) window of a 2-D image, indexed by its top-left pixel:
    ``sliding_window_view(image, (rows, cols))``'s array (the same shape, strides and pixels),
    built by one ``as_strided`` call, without sliding_window_view's argument checks (~25 us a
    call, 16 calls per KITTI frame; issue 8)."""
    h, w = image.shape
    s0, s1 = image.strides
    return as_strided(image, (h - rows + 1, w - cols + 1, rows, cols), (s0, s1, s0, s1), writeable=False)


def _centre_sad(patch_l: np.ndarray, band: np.ndarray, n_shifts: int, sum_type) -> np.ndarray:
    """SAD of each uint8 left patch (K,P,P) against the P-wide windows of its right band
    (K,P,P+n_shifts-1) at every shift, each minus its centre pixel (ORB-SLAM2's
    ComputeStereoMatches): Σ|(R − R_c) − (L − L_c)|, as a (K, n_shifts) float64 view.

    int16 differences of uint8 pixels, one window shift at a time, with the keypoints on the
    innermost axis: the patches are laid out (P,P,K) once, so every operation below runs over
    contiguous rows of K values (in the (K,P,P) layout a shifted window is a strided view whose
    inner runs are 11 pixels long, ~3x slower per subtraction; issue 8, docs/notes/s15-trackcpu.md).
    The sums are exact integers (|differences| <= 510, P² of them fit ``sum_type``), so the
    values do not depend on the order of the additions: the same SADs as the (K,P,P) loop."""
    P = patch_l.shape[1]
    w = P // 2
    k = len(patch_l)
    pl = patch_l.transpose(1, 2, 0).astype(np.int16, order="C")     # (P,P,K)
    bd = band.transpose(1, 2, 0).astype(np.int16, order="C")         # (P,P+n_shifts-1,K)
    pl -= pl[w, w]                                                   # the centred left patch
    sad = np.empty((n_shifts, k), np.float64)
    diff = np.empty((P, P, k), np.int16)  # one buffer for every shift (no temporaries)
    # |differences| are >= 0: read as uint16 for the 16-bit sums (the same values, no cast)
    flat = diff.reshape(P * P, k)
    flat = flat.view(np.uint16) if sum_type == np.uint16 else flat
    for shift in range(n_shifts):
        # window at this shift minus the centred left patch, minus the window's centre pixel
        np.subtract(bd[:, shift:shift + P], pl, out=diff)
        diff -= bd[w, shift + w]
        np.abs(diff, out=diff)
        sad[shift] = flat.sum(axis=0, dtype=sum_type)
    return sad.T


def _zero_mean_sad(patch_l: np.ndarray, band: np.ndarray, n_shifts: int) -> np.ndarray:
    """Zero-mean SAD of each left patch (K,P,P) against the P-wide windows of its right band
    (K,P,P+n_shifts-1) at every shift: Σ|(R − mean R) − (L − mean L)|. Exact in integers: with
    n = P² pixels, n·x − Σx is n times the zero-mean value (|n·(R−L)| ≤ 121·510 for 11×11: int32),
    divided by n at the end."""
    k, P = patch_l.shape[0], patch_l.shape[1]
    n = P * P
    pl = patch_l.astype(np.int32) * n
    pl -= patch_l.reshape(k, -1).sum(axis=1, dtype=np.int32)[:, None, None]
    band_n = band.astype(np.int32) * n
    # window sums of the band at every shift from cumulative column sums
    cols = np.zeros((k, band.shape[2] + 1), np.int64)
    np.cumsum(band.sum(axis=1, dtype=np.int32), axis=1, out=cols[:, 1:])
    sad = np.empty((k, n_shifts), np.float64)
    diff = np.empty(pl.shape, np.int32)
    for shift in range(n_shifts):
        np.subtract(band_n[:, :, shift:shift + P], pl, out=diff)
        diff -= (cols[:, shift + P] - cols[:, shift]).astype(np.int32)[:, None, None]
        np.abs(diff, out=diff)
        sad[:, shift] = diff.reshape(k, -1).sum(axis=1, dtype=np.int64)
    return sad / n


def stereo_candidates(left: Features, right: Features, tol: np.ndarray, octave_tolerance: int):
    """(left, right) keypoint pairs on the same row band (|v_r - v_l| <= tol per left keypoint)
    whose pyramid levels differ by at most ``octave_tolerance``, grouped by left keypoint; and each
    right keypoint's rank in row order (for ties). The right keypoints are searched level by level
    (one row-sorted array per level), so pairs on incompatible levels are never formed: about
    2.5x fewer pairs than one row band over all levels filtered afterwards (KITTI)."""
    order = np.argsort(right.uv[:, 1], kind="stable")
    row_rank = np.empty(len(right), np.int64)
    row_rank[order] = np.arange(len(right))
    by_level = order[np.argsort(right.octave[order], kind="stable")]   # by level, then row
    levels, first = np.unique(right.octave[by_level], return_index=True)
    ends = np.r_[first[1:], len(by_level)]
    # float64 once: searchsorted compares in the common type (float64 with the float64 bounds) and
    # would cast the float32 rows again on every call
    v_sorted = right.uv[by_level, 1].astype(np.float64)
    lo_v, hi_v = left.uv[:, 1] - tol, left.uv[:, 1] + tol
    # per left keypoint, one range of by_level per right level (empty where the levels are too far)
    lo = np.zeros((len(left), len(levels)), np.int64)
    hi = np.zeros((len(left), len(levels)), np.int64)
    for g, (lvl, a, b) in enumerate(zip(levels, first, ends)):
        near = np.flatnonzero(np.abs(left.octave - lvl) <= octave_tolerance)
        lo[near, g] = a + np.searchsorted(v_sorted[a:b], lo_v[near], side="left")
        hi[near, g] = a + np.searchsorted(v_sorted[a:b], hi_v[near], side="right")
    counts = np.maximum(hi - lo, 0)
    per_left = counts.sum(axis=1)
    counts = counts.reshape(-1)
    total = int(per_left.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), row_rank
    pos = np.repeat(lo.reshape(-1) - np.cumsum(counts) + counts, counts) + np.arange(total)
    # the left keypoint of every pair: each one's pairs are consecutive (its ranges are laid out
    # left keypoint by left keypoint), so one repeat by its total, not a repeat over every
    # (keypoint, level) range and an integer division of every pair (issue 8)
    return np.repeat(np.arange(len(left)), per_left), by_level[pos], row_rank


def match_stereo(left: Features, right: Features | None, left_img: np.ndarray, right_img: np.ndarray,
                 calib: StereoCalibration, params: TrackingParams,
                 noise_sigma: float | None = None, pyramids: PairPyramids | None = None,
                 sensor_sigma: float | None = None) -> StereoMatches:
    """``noise_sigma``: the left image's noise (track_health.image_noise_sigma); with it the SAD
    outlier test is stricter on low-SNR (hazy, noisy) frames (canopy.frontend.noisy_features).
    ``sensor_sigma``: the enhancement's own noise sigma of the frame, which opens the fill-in on
    frames it changed (``stereo_fill.fill_active``); None where it was not handed over.
    With ``stereo_matcher: flow`` the right columns come from LK flow (canopy.frontend.stereo_flow)
    and ``right`` is not used (may be None). ``pyramids``: ``PairPyramids`` of the raw pair, if
    built ahead (the refinement uses them when it runs on the raw pair)."""
    if params.stereo_matcher == "flow":
        from canopy.frontend.stereo_flow import match_stereo_flow  # imports this module
        return match_stereo_flow(left, left_img, right_img, calib, params, noise_sigma)
    n = len(left)
    u_right = np.full(n, -1.0, np.float32)
    depth = np.full(n, -1.0, np.float32)
    if n == 0 or len(right) == 0:
        return StereoMatches(u_right, depth)
    scale_factors = params.scale_factor ** np.arange(params.n_levels)
    max_disp = params.max_disparity_fraction * calib.width

    tol = params.row_tolerance * scale_factors[left.octave]
    qi, rj, row_rank = stereo_candidates(left, right, tol, params.octave_tolerance)
    # gathers from contiguous 1-D columns (~3x faster than from the (N,2) rows); the same values
    disp = np.ascontiguousarray(left.uv[:, 0])[qi] - np.ascontiguousarray(right.uv[:, 0])[rj]
    ok = np.flatnonzero((disp >= params.min_disparity) & (disp <= max_disp))
    qi, rj = qi[ok], rj[ok]
    dist = hamming_pairs(as_words(left.descriptors), as_words(right.descriptors), qi, rj)
    # equal distances go to the right keypoint higher in the image (the order of a plain row search)
    best_ref, best_d, second_d = best_two(qi, rj, dist, n, tie_rank=row_rank)
    good = (best_ref >= 0) & (best_d <= params.stereo_max_hamming) & (best_d < params.stereo_ratio * second_d)
    li = np.flatnonzero(good)
    ri = best_ref[li]
    keep = unique_by_reference(li, ri, best_d[li])
    li, ri = li[keep], ri[keep]

    fill = noisy_haze = False
    if params.stereo_fill:  # hazy frames: flow for the unmatched keypoints (canopy.frontend.stereo_fill)
        from canopy.frontend.stereo_fill import fill_active, fill_unmatched_by_flow  # imports this module
        fill = fill_active(left, params, left_img, noise_sigma, sensor_sigma)
    if params.subpixel_mean_on_noisy_haze:  # hazy frames of a noisy sensor (smoothed pair, no fill-in)
        from canopy.frontend.stereo_fill import mean_on_noisy_haze  # imports this module
        noisy_haze = mean_on_noisy_haze(left, params, left_img, noise_sigma)
    # the fill-in's frames (and hazy noisy ones): zero-mean SAD for every match of the frame (the module docstring)
    mean = (fill and params.subpixel_mean_on_fill) or noisy_haze
    normalise = "mean" if mean else params.subpixel_normalise
    ref_left, ref_right, _ = refinement_pair(left_img, right_img, params, left.robust_noise_sigma)
    li, ur, disp = refine_and_accept(ref_left, ref_right, left, li, right.uv[ri, 0].astype(np.float64),
                                     scale_factors, max_disp, params, noise_sigma, pyramids, normalise,
                                     raw_pair=(left_img, right_img))
    u_right[li] = ur
    depth[li] = calib.bf / disp
    out = StereoMatches(u_right, depth, n_candidates=len(qi))
    if fill:
        out = fill_unmatched_by_flow(out, left, left_img, right_img, calib, params, noise_sigma, pyramids,
                                     normalise)
    return out


def refine_and_accept(ref_left: np.ndarray, ref_right: np.ndarray, left: Features, li: np.ndarray,
                      ur0: np.ndarray, scale_factors: np.ndarray, max_disp: float, params: TrackingParams,
                      noise_sigma: float | None,
                      pyramids: PairPyramids | None = None,
                      normalise: str | None = None,
                      raw_pair: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tail every stereo matcher shares: left keypoints ``li`` with a first right column ``ur0``
    -> (kept indices, refined right column, disparity) after the sub-pixel SAD search, the rig's
    disparity offset, the disparity range and the SAD acceptance test. ``normalise``: the SAD's
    patch normalisation (``subpixel_refine``) if not ``params.subpixel_normalise``. ``raw_pair``: the
    frame's own (left, right) images when ``ref_left`` / ``ref_right`` are a smoothed copy
    (``noisy_features.refinement_pair``): with ``subpixel_raw_vertex_search`` the vertex is then
    measured on them (``raw_vertex``)."""
    uvl, octave = left.uv[li].astype(np.float64), left.octave[li]
    normalise = normalise or params.subpixel_normalise
    ur, sad, ok = subpixel_refine(ref_left, ref_right, uvl, ur0, octave, scale_factors, params.subpixel_window,
                                  params.subpixel_search, normalise, pyramids)
    if raw_pair is not None and params.subpixel_raw_vertex_search > 0 and raw_pair[0] is not ref_left:
        ur, ok = raw_vertex(raw_pair, uvl, ur, ok, octave, scale_factors, params, normalise, pyramids)
    li, ur, sad = li[ok], ur[ok], sad[ok]
    # the rig's constant disparity offset (canopy.frontend.disparity_offset): u_right moves with it
    ur = ur - params.disparity_offset_for(left.extractor)
    disp = left.uv[li, 0] - ur
    ok = (disp >= params.min_disparity) & (disp <= max_disp)
    li, ur, sad, disp = li[ok], ur[ok], sad[ok], disp[ok]
    if len(sad):
        ok = accept_sad(sad, params, noise_sigma)
        li, ur, disp = li[ok], ur[ok], disp[ok]
    return li, ur, disp
