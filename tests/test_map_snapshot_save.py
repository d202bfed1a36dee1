"""The map a paused client is shown is the map it saves (actors.local_mapping), and a map saved
after keyframe culling loads consistent (canopy.loop.map_io, canopy.backend.keyframe_culling).

Local mapping publishes its map at most every ``snapshot_period_s``. Before the rate cap had a
trailing edge, a keyframe inserted within the period of the previous snapshot stayed unpublished
until the next keyframe: with a keyframe every 3 frames on EuRoC, a run paused after a few frames
showed a one-keyframe map (the ``map`` request, the deltas) while ``save_map`` wrote two
(test_inspection_stream.py's real run failed on the point count, 413 shown against 454 saved).
These tests drive the actor's own methods on keyframes tracked from the bundled EuRoC snippet,
with a transport stand-in that records what the actor publishes: no clock, no processes.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from actors.local_mapping import LocalMappingActor
from canopy.backend import LocalMapper
from canopy.config import load_run_config
from canopy.frontend import Tracker
from canopy.loop.map_io import load_map, map_place_keyframes, restore_mapper
from canopy.sources import open_source
from protocol.messages import MapSaved, MapSnapshot, SaveMapRequest

N_FRAMES = 31          # a keyframe every 3 frames: 11 keyframes of the still MAV
KEEP_RECENT = 2        # small, so that the snippet's keyframes are culled


class _Transport:
    """What LocalMappingActor uses of ActorContext, recording the published messages."""

    def __init__(self):
        self.published: list = []
        self.extra: dict = {}

    def publish(self, msg) -> None:
        self.published.append(msg)

    def send(self, target, msg, block=True) -> bool:
        return True

    def has_output(self, target) -> bool:
        return False

    def stop(self) -> None:
        pass

    def last(self, kind):
        return next((m for m in reversed(self.published) if isinstance(m, kind)), None)


@pytest.fixture(scope="module")
def euroc_keyframes():
    """Keyframes tracked on the EuRoC snippet with a 3-frame cadence and culling keeping the newest 2
    (each map update applied before the next frame)."""
    src = open_source("euroc", max_frames=N_FRAMES)
    cfg = load_run_config("euroc")
    tracking = replace(cfg.tracking, max_frames_between_keyframes=3)
    mapping = replace(cfg.mapping, window_min_view_change_px=1.0, keyframe_culling=True,
                      keyframe_culling_keep_recent=KEEP_RECENT)
    tracker, mapper = Tracker(src.calibration, tracking), LocalMapper(src.calibration, mapping)
    keyframes = []
    for i in range(len(src)):
        res = tracker.track(src.frame(i))
        if res.is_keyframe and res.keyframe is not None:
            keyframes.append(res.keyframe)
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
    assert len(keyframes) >= 8 and mapper.n_keyframes_culled >= 2, (len(keyframes), mapper.n_keyframes_culled)
    return src.calibration, mapping, keyframes


def _actor(calib, mapping, period_s: float):
    """The actor as just after a snapshot: every keyframe given to it falls within ``period_s``."""
    actor = LocalMappingActor({"calib": calib, "params": mapping, "snapshot_period_s": period_s})
    ctx = _Transport()
    actor.setup(ctx)
    actor.last_snapshot = time.monotonic()
    return actor, ctx


def _same_map(snap: MapSnapshot, mapper) -> None:
    """The snapshot holds the mapper's landmarks (ids and positions) and every keyframe, culled ones
    through their parents."""
    ids = np.asarray(snap.point_ids, np.int64)
    assert sorted(ids.tolist()) == sorted(mapper.landmarks)
    pos = np.array([mapper.landmarks[i].position for i in ids.tolist()], np.float32).reshape(-1, 3)
    np.testing.assert_array_equal(np.asarray(snap.points, np.float32), pos)
    assert sorted(np.asarray(snap.keyframe_indices).tolist()) == sorted(set(mapper.keyframes) |
                                                                        set(mapper.culled_keyframes))


def test_a_paused_client_is_shown_the_map_it_saves(tmp_path, euroc_keyframes):
    calib, mapping, keyframes = euroc_keyframes
    actor, ctx = _actor(calib, mapping, period_s=3600.0)   # every later keyframe within the period
    for kf in keyframes:
        actor.on_message(kf, ctx)
    assert actor.mapper.n_keyframes_culled >= 2
    assert ctx.last(MapSnapshot) is None   # the cap withheld every change so far
    # the change is due once the period has passed, though no keyframe follows (the run is paused)
    assert actor.next_tick_s() is not None and actor.next_tick_s() > 0
    path = tmp_path / "paused.canopy"
    actor.on_control(SaveMapRequest(path=str(path)), ctx)
    saved = ctx.published[-1]
    assert isinstance(saved, MapSaved) and saved.ok, saved
    shown = ctx.last(MapSnapshot)          # published just before the map was written
    _same_map(shown, actor.mapper)
    data = load_map(path, calib)
    assert sorted(data.lm_id.tolist()) == sorted(np.asarray(shown.point_ids).tolist())
    assert len(data.lm_id) == saved.points and len(data.kf_index) == saved.keyframes
    # the saved keyframes are the ones left; the snapshot's others are exactly the culled ones
    assert set(np.asarray(shown.keyframe_indices).tolist()) - set(data.kf_index.tolist()) == \
        set(actor.mapper.culled_keyframes)
    assert actor.next_tick_s() is None     # nothing left to publish


def test_the_last_change_is_published_when_its_period_is_over(euroc_keyframes):
    calib, mapping, keyframes = euroc_keyframes
    actor, ctx = _actor(calib, mapping, period_s=3600.0)
    for kf in keyframes[:3]:
        actor.on_message(kf, ctx)
    n_before = sum(isinstance(m, MapSnapshot) for m in ctx.published)
    assert 0 < actor.next_tick_s() <= 3600.0
    actor.last_snapshot -= 3600.0          # the period is over, no keyframe came
    assert actor.next_tick_s() <= 0
    actor.on_tick(ctx)
    assert sum(isinstance(m, MapSnapshot) for m in ctx.published) == n_before + 1
    _same_map(ctx.last(MapSnapshot), actor.mapper)
    assert actor.next_tick_s() is None


def test_a_map_saved_after_culling_loads_consistent(tmp_path, euroc_keyframes):
    calib, mapping, keyframes = euroc_keyframes
    actor, ctx = _actor(calib, mapping, period_s=0.0)
    for kf in keyframes:
        actor.on_message(kf, ctx)
    culled = set(actor.mapper.culled_keyframes)
    assert len(culled) >= 2
    path = tmp_path / "culled.canopy"
    actor.on_control(SaveMapRequest(path=str(path)), ctx)
    data = load_map(path, calib)
    assert not culled & set(data.kf_index.tolist())
    lm_set = set(data.lm_id.tolist())
    observed = set()
    for k in range(len(data.kf_index)):
        lids = data.landmark[data.keyframe_rows(k)]
        lids = lids[lids >= 0].tolist()
        assert lids, f"keyframe {data.kf_index[k]} saved without any observation"
        assert set(lids) <= lm_set                       # no keypoint refers to a landmark not saved
        assert len(lids) == len(set(lids))               # a landmark once per keyframe
        observed.update(lids)
    assert observed == lm_set                            # no landmark without a saved observer
    assert set(data.covisibility[:, :2].ravel().tolist()) <= set(data.kf_index.tolist())
    # restored, the map is the one saved, both indices in step
    restored = LocalMapper(calib, mapping)
    restore_mapper(data, restored)
    assert sorted(restored.keyframes) == sorted(actor.mapper.keyframes)
    for lid, lm in actor.mapper.landmarks.items():
        assert restored.landmarks[lid].obs == lm.obs
    for k, rec in restored.keyframes.items():
        for i in np.flatnonzero(rec.landmark >= 0).tolist():
            assert restored.landmarks[int(rec.landmark[i])].obs[k] == i
    # relocalisation's view of it: every observed keypoint has its landmark's position
    for pk in map_place_keyframes(data):
        assert np.isfinite(pk.landmark_positions[pk.landmark_ids >= 0]).all()
