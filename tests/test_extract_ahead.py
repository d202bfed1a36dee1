"""Lockstep tracking extracts a frame's features before it waits for the map updates due at that
frame (``Tracker.extract`` / ``Tracker.track_extracted``, ``runtime.lockstep_extract_ahead``): the
extraction overlaps local mapping's BA, and the results are those of ``Tracker.track`` with the
updates applied first, bit for bit."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canopy.backend import LocalMapper
from canopy.config import load_run_config
from canopy.frontend import Tracker
from canopy.pipeline import MapUpdateSchedule
from canopy.sources import open_source
from shared.types import StereoFrame


@pytest.fixture(scope="module")
def kitti():
    src = open_source("kitti", None, max_frames=12)
    return src, [src.frame(i) for i in range(len(src))], load_run_config("kitti")


def _lockstep(frames, calib, cfg, ahead: bool, lag: int = 1, parallel: bool = True):
    """The tracking actor's lockstep loop in one process: each keyframe's map update (local BA done
    at once) is applied before frame index + 1 + ``lag``; the frame's features are extracted before
    (``ahead``) or after those updates are applied."""
    tracker = Tracker(calib, replace(cfg.tracking, parallel_stereo=parallel))
    mapper = LocalMapper(calib, cfg.mapping)
    schedule = MapUpdateSchedule(lag)
    out = []
    for frame in frames:
        extracted = tracker.extract(frame) if ahead else None
        assert schedule.missing(frame.index) is None  # computed at once below: never waited for
        for update in schedule.take_due(frame.index):
            tracker.apply_map_update(update)
        res = tracker.track_extracted(extracted) if ahead else tracker.track(frame)
        out.append((res.status, res.T_world_cam.copy(), res.n_inliers, res.n_matches, res.n_stereo,
                    res.is_keyframe, res.reference_kf_index))
        if res.is_keyframe:
            kf = res.keyframe
            out.append((kf.uv.copy(), kf.u_right.copy(), kf.depth.copy(), kf.descriptors.copy(),
                        kf.landmark_ids.copy(), kf.new_landmark_ids.copy()))
            schedule.keyframe_sent(kf.index, res.index)
            schedule.hold(mapper.insert_keyframe(kf))
    return out


def _assert_identical(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert len(x) == len(y)
        for u, v in zip(x, y):
            assert np.array_equal(np.asarray(u), np.asarray(v))


@pytest.mark.parametrize("lag", [0, 1])
def test_extracting_before_the_map_updates_gives_identical_results(kitti, lag):
    src, frames, cfg = kitti
    before = _lockstep(frames, src.calibration, cfg, ahead=False, lag=lag)
    ahead = _lockstep(frames, src.calibration, cfg, ahead=True, lag=lag)
    assert sum(len(r) == 6 for r in before) >= 3  # keyframes were made, so updates were applied
    _assert_identical(before, ahead)


def test_extracting_ahead_on_dark_noisy_frames_with_the_serial_path(kitti):
    """The noise-floored FAST threshold and the serial stereo path (no worker) as well: a dark,
    noisy copy of the frames (the grid's kind of degradation)."""
    src, frames, cfg = kitti
    rng = np.random.default_rng(0)
    dark = []
    for f in frames[:8]:
        noisy = [np.clip(img * 0.3 + rng.normal(0, 4, img.shape), 0, 255).astype(np.uint8)
                 for img in (f.left, f.right)]
        dark.append(StereoFrame(f.index, f.timestamp, *noisy))
    before = _lockstep(dark, src.calibration, cfg, ahead=False, parallel=False)
    ahead = _lockstep(dark, src.calibration, cfg, ahead=True, parallel=False)
    _assert_identical(before, ahead)


def test_track_extracted_leaves_the_paused_time_out_of_the_total(kitti):
    src, frames, cfg = kitti
    tracker = Tracker(src.calibration, cfg.tracking)
    ex = tracker.extract(frames[0])
    res = tracker.track_extracted(ex, paused_s=1000.0)  # 1000 s "waited": far more than the frame took
    assert res.timings["total"] < 0 < res.timings["total_cpu"]
