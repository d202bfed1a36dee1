"""Tracking speed changes keep every result (issue 8, speed): the right image on the worker thread,
the dense-table local-map search, the per-level stereo candidates and the batched SAD give what
the serial / straightforward computations give, on real KITTI frames."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canopy.backend import LocalMapper
from canopy.config import load_run_config
from canopy.frontend import Tracker
from canopy.frontend.features import OrbExtractor
from canopy.frontend.matching import (as_words, band_pairs, best_two, floor_divide, grid_pairs_grouped, hamming_pairs,
                                      match_in_window)
from canopy.frontend.stereo import PairPyramids, match_stereo, stereo_candidates, subpixel_refine
from canopy.sources import open_source


@pytest.fixture(scope="module")
def kitti():
    src = open_source("kitti", None, max_frames=14)
    return src, [src.frame(i) for i in range(len(src))], load_run_config("kitti")


@pytest.fixture(scope="module")
def kitti_features(kitti):
    _, frames, cfg = kitti
    ex = OrbExtractor(cfg.tracking)
    return ex.extract(frames[0].left), ex.extract(frames[0].right), frames[0]


def _run(frames, calib, cfg, parallel: bool):
    """In-process lockstep, map updates applied at once: every result of every frame."""
    tracker = Tracker(calib, replace(cfg.tracking, parallel_stereo=parallel))
    mapper = LocalMapper(calib, cfg.mapping)
    out = []
    for frame in frames:
        res = tracker.track(frame)
        out.append((res.status, res.T_world_cam.copy(), res.n_inliers, res.n_matches, res.n_stereo, res.is_keyframe))
        if res.is_keyframe:
            kf = res.keyframe
            out.append((kf.u_right.copy(), kf.depth.copy(), kf.landmark_ids.copy(), kf.new_landmark_ids.copy()))
            tracker.apply_map_update(mapper.insert_keyframe(kf))
    return tracker, out


def test_worker_thread_stereo_gives_identical_results(kitti):
    src, frames, cfg = kitti
    tracker, par = _run(frames, src.calibration, cfg, parallel=True)
    assert tracker._parallel_stereo
    _, ser = _run(frames, src.calibration, cfg, parallel=False)
    assert len(par) == len(ser) > len(frames)  # keyframes were made
    for a, b in zip(par, ser):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert np.array_equal(np.asarray(x), np.asarray(y))
    # the worker's own stage is reported, and the tracking thread no longer matches stereo itself
    res = tracker.track(frames[-1])
    assert "stereo_worker_cpu" in res.timings and "orb_cpu" in res.timings
    # clean KITTI: the SAD pyramids were built ahead, while the worker waited for the left keypoints
    assert "stereo_pyramids_cpu" in res.timings


def _old_grid_pairs_grouped(q_uv, r_uv, r_group, cells):
    """The search before the dense cell table: two binary searches per row range."""
    cells = np.maximum(np.asarray(cells, float), 1.0)
    n_groups = len(cells)
    lo_uv = np.minimum(q_uv.min(axis=0), r_uv.min(axis=0))
    span = np.maximum(q_uv.max(axis=0), r_uv.max(axis=0)) - lo_uv
    n_cols = (span[0] // cells).astype(np.int64) + 3
    n_rows = (span[1] // cells).astype(np.int64) + 3
    offset = np.concatenate([[0], np.cumsum(n_cols * n_rows)[:-1]])
    rc = ((r_uv - lo_uv) // cells[r_group][:, None]).astype(np.int64)
    rkey = offset[r_group] + rc[:, 1] * n_cols[r_group] + rc[:, 0]
    order = np.argsort(rkey, kind="stable")
    qc = ((q_uv - lo_uv)[:, None, :] // cells[None, :, None]).astype(np.int64)
    row = qc[:, :, None, 1] + np.array([-1, 0, 1])
    base = offset[None, :, None] + row * n_cols[None, :, None]
    lo = np.where(row >= 0, base + np.maximum(qc[:, :, None, 0] - 1, 0), 1)
    hi = np.where(row >= 0, base + qc[:, :, None, 0] + 1, 0)
    needle, rpos = band_pairs(lo.reshape(-1), hi.reshape(-1), rkey[order])
    return needle // (3 * n_groups), order[rpos]


def test_local_map_search_equals_the_binary_search_and_brute_force(kitti_features):
    left, _, _ = kitti_features
    rng = np.random.default_rng(3)
    # projected landmarks: keypoints moved by a few pixels (as a predicted pose leaves them)
    q_uv = left.uv.astype(np.float64) + rng.normal(0, 2.0, left.uv.shape)
    scale = 1.2 ** left.octave
    scales, group = np.unique(scale, return_inverse=True)
    for cells in (np.array([10.0]), 4.0 * scales):
        g = np.zeros(len(left), np.int64) if len(cells) == 1 else group.reshape(-1)
        new = grid_pairs_grouped(q_uv, left.uv, g, cells)
        old = _old_grid_pairs_grouped(q_uv, left.uv, g, cells)
        assert len(new[0]) > len(left) and all(np.array_equal(a, b) for a, b in zip(new, old))
    # the matcher against brute force: every pair within the circle, best Hamming, ratio, unique
    words = as_words(left.descriptors)
    q_words = words[rng.permutation(len(words))]  # descriptors that are often far: ratio test at work
    q_words[::2] = words[::2]
    radius = np.full(len(q_uv), 4.0)
    q, r, d = match_in_window(q_uv, q_words, radius, left.uv, words, 75, 0.8, r_scale=scale)
    d2 = ((q_uv[:, None, :] - left.uv[None, :, :].astype(np.float64)) ** 2).sum(-1)
    inside = d2 <= (radius[:, None] * scale[None, :]) ** 2
    ii, jj = np.nonzero(inside)
    ham = hamming_pairs(q_words, words, ii, jj)
    best_ref, best_d, second_d = best_two(ii, jj, ham, len(q_uv))
    assert len(q) > 100
    # every returned match is the query's (distance-)best candidate and passes the tests
    assert np.array_equal(d, best_d[q]) and np.all(d <= 75) and np.all(d < 0.8 * second_d[q])
    assert len(np.unique(r)) == len(r)


def test_stereo_candidates_equal_one_row_band_filtered_afterwards(kitti_features):
    left, right, _ = kitti_features
    p = load_run_config("kitti").tracking
    tol = p.row_tolerance * (p.scale_factor ** np.arange(p.n_levels))[left.octave]
    # before: one row band over every right keypoint, the octave test afterwards
    order = np.argsort(right.uv[:, 1], kind="stable")
    qi, rpos = band_pairs(left.uv[:, 1] - tol, left.uv[:, 1] + tol, right.uv[order, 1])
    rj = order[rpos]
    ok = np.abs(left.octave[qi] - right.octave[rj]) <= p.octave_tolerance
    qi, rj = qi[ok], rj[ok]
    nq, nr, rank = stereo_candidates(left, right, tol, p.octave_tolerance)
    assert len(nq) == len(qi) > 1000
    assert set(zip(nq.tolist(), nr.tolist())) == set(zip(qi.tolist(), rj.tolist()))
    wl, wr = as_words(left.descriptors), as_words(right.descriptors)
    before = best_two(qi, rj, hamming_pairs(wl, wr, qi, rj), len(left))
    after = best_two(nq, nr, hamming_pairs(wl, wr, nq, nr), len(left), tie_rank=rank)
    assert all(np.array_equal(a, b) for a, b in zip(before, after))


def _sad_reference(left_img, right_img, uvl, ur, octave, scale_factors, w, L, normalise="centre"):
    """ORB-SLAM2's SAD search written out keypoint by keypoint: patches minus their centre pixel
    (int64 sums), or minus their mean (``normalise="mean"``, float64; tests/test_haze_stereo.py)."""
    import cv2
    dtype = np.float64 if normalise == "mean" else np.int64

    def flat(p):
        p = p.astype(dtype)
        return p - (p.mean() if normalise == "mean" else p[w, w])

    h0, w0 = left_img.shape
    u_out, sad_out, ok_out = np.full(len(uvl), -1.0), np.full(len(uvl), np.inf), np.zeros(len(uvl), bool)
    for i in range(len(uvl)):
        s = scale_factors[octave[i]]
        size = (int(round(w0 / s)), int(round(h0 / s)))
        il = left_img if octave[i] == 0 else cv2.resize(left_img, size, interpolation=cv2.INTER_LINEAR)
        ir = right_img if octave[i] == 0 else cv2.resize(right_img, size, interpolation=cv2.INTER_LINEAR)
        xl, yl, xr = (int(np.round(uvl[i, 0] / s)), int(np.round(uvl[i, 1] / s)), int(np.round(ur[i] / s)))
        hh, ww = il.shape
        if not (yl - w >= 0 and yl + w < hh and xl - w >= 0 and xl + w < ww and xr - L - w >= 0 and xr + L + w < ww):
            continue
        pl = flat(il[yl - w:yl + w + 1, xl - w:xl + w + 1])
        costs = [float(np.abs(flat(ir[yl - w:yl + w + 1, xr + d - w:xr + d + w + 1]) - pl).sum())
                 for d in range(-L, L + 1)]
        best = int(np.argmin(costs))
        u_out[i], sad_out[i] = s * (xr + best - L), costs[best]
        if 0 < best < 2 * L:
            d1, d2, d3 = costs[best - 1], costs[best], costs[best + 1]
            denom = 2.0 * (d1 + d3 - 2.0 * d2)
            delta = (d1 - d3) / denom if denom > 0 else 0.0
            u_out[i] = s * (xr + (best - L) + delta)
            ok_out[i] = abs(delta) <= 1.0
    return u_out, sad_out, ok_out


def test_batched_sad_equals_the_keypoint_by_keypoint_search(kitti_features):
    left, right, frame = kitti_features
    p = load_run_config("kitti").tracking
    stereo = match_stereo(left, right, frame.left, frame.right, open_source("kitti", None, max_frames=1).calibration, p)
    li = np.flatnonzero(stereo.valid)[::5]
    sf = p.scale_factor ** np.arange(p.n_levels)
    ur0 = stereo.u_right[li].astype(np.float64) + np.round(np.random.default_rng(0).normal(0, 2, len(li)))
    args = (frame.left, frame.right, left.uv[li].astype(np.float64), ur0, left.octave[li], sf,
            p.subpixel_window, p.subpixel_search)
    got = subpixel_refine(*args)
    ref = _sad_reference(*args)
    # pyramids built ahead give the same result; built from other images, they are not used
    ahead = subpixel_refine(*args, pyramids=PairPyramids.build(frame.left, frame.right, sf))
    other = PairPyramids.build(frame.left.copy(), np.zeros_like(frame.right), sf)
    assert not other.serves(frame.left, frame.right)
    for g in (ahead, subpixel_refine(*args, pyramids=other)):
        assert all(np.array_equal(a, b) for a, b in zip(got, g))
    assert got[2].sum() > 50 and len(np.unique(left.octave[li])) >= 4
    assert np.array_equal(got[2], ref[2]) and np.array_equal(got[1], ref[1])
    assert np.allclose(got[0], ref[0], rtol=0, atol=1e-9)


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="Linux /proc scheduler statistics")
def test_thread_schedstat_counts_this_threads_cpu():
    import threading
    import time

    from actors.schedstat import thread_report, thread_schedstat
    me = threading.get_native_id()
    start = thread_schedstat()
    t0 = time.thread_time()
    x = 0
    while time.thread_time() - t0 < 0.2:  # 0.2 s of CPU on this thread
        x += 1
    rep = thread_report(start, thread_schedstat(), {me: "main"}, n_frames=4)
    assert 0.18 <= rep["main"]["cpu_s"] <= 0.5
    assert rep["main"]["cpu_ms_per_frame"] == pytest.approx(rep["main"]["cpu_s"] * 1e3 / 4, rel=1e-3)
    assert rep["main"]["runqueue_wait_s"] >= 0


@pytest.mark.parametrize("parallel", [False, True])
def test_left_noise_sigma_is_measured_once_per_frame(kitti, monkeypatch, parallel):
    """The tracker's FAST-floor sigma of the left image goes to the cell extractor's fallback floor
    instead of being measured again: one measurement of the left image and one of the right per
    frame (that the features do not change: test_cell_extractor's given-sigma test)."""
    import canopy.frontend.cell_extractor as cell_extractor
    import canopy.frontend.tracker as tracker_module
    from canopy.frontend.track_health import image_noise_sigma

    src, frames, cfg = kitti
    params = replace(cfg.tracking, parallel_stereo=parallel)
    assert params.extractor == "cells" and params.fast_noise_factor > 0 and params.cell_fallback_noise_factor > 0
    measured = []

    def counting(image):
        measured.append(id(image))
        return image_noise_sigma(image)

    monkeypatch.setattr(tracker_module, "image_noise_sigma", counting)
    monkeypatch.setattr(cell_extractor, "image_noise_sigma", counting)
    tracker = Tracker(src.calibration, params)
    res = tracker.track(frames[0])
    assert res.status != "lost"
    assert sorted(measured) == sorted([id(frames[0].left), id(frames[0].right)])


def test_floor_divide_equals_numpys_floor_division_where_rounding_could_differ():
    """floor(a / b) with numpy's ``//`` where the quotient is integral: the same values as ``//``
    on multiples of the divisor, their float neighbours (where a / b rounds up to the next
    integer: 0.30000000000000004 // 0.1 is 2, floor(0.30000000000000004 / 0.1) would be 3),
    pixel coordinates over cell sizes, negative values, zeros and non-finite values."""
    rng = np.random.default_rng(3)
    b = np.concatenate([[0.1, 0.3, 1.0, 4.0, 4.8, 5.76, 6.912, 14.3327232], rng.uniform(1.0, 60.0, 40)])
    k = np.arange(-50, 400, dtype=float)
    mult = k[:, None] * b[None, :]
    a = np.stack([mult, np.nextafter(mult, -np.inf), np.nextafter(mult, np.inf)], axis=0)
    bb = np.broadcast_to(b, a.shape)
    with np.errstate(all="ignore"):
        assert np.array_equal(floor_divide(a, bb), a // bb)
        assert (floor_divide(a, bb) != np.floor(a / bb)).any()  # the case the fallback is there for
        uv = rng.uniform(0, 1241, (5000, 2)).astype(np.float32) - np.float32(0.5)
        assert np.array_equal(floor_divide(uv[:, None, :], b[None, :, None]), uv[:, None, :] // b[None, :, None])
        odd = np.array([0.0, -0.0, 1e-300, -1e-300, np.inf, -np.inf, np.nan, 7.0])
        for d in (0.0, 2.5, -2.5, np.inf):
            assert np.array_equal(floor_divide(odd, d), odd // d, equal_nan=True)
    ints = np.arange(-7, 8)
    assert np.array_equal(floor_divide(ints, 3), ints // 3) and floor_divide(ints, 3).dtype == ints.dtype
