"""Pipelined lockstep (canopy.pipeline.MapUpdateSchedule): each local-map update is applied before
a fixed frame, never as it happens to arrive, so tracking may overlap local BA and stay repeatable."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from canopy.config import RuntimeParams
from canopy.pipeline import MapUpdateSchedule
from shared.errors import ConfigError


def _update(kf: int, tag: str = ""):
    return SimpleNamespace(keyframe_index=kf, tag=tag)


def test_lag_zero_applies_each_update_before_the_next_frame():
    s = MapUpdateSchedule(0)
    s.keyframe_sent(keyframe_index=3, frame_index=3)
    assert s.missing(4) == 3                        # tracking must wait for it
    s.hold(_update(3))
    assert s.missing(4) is None
    assert [u.keyframe_index for u in s.take_due(4)] == [3]
    assert s.take_due(5) == []


def test_lag_one_holds_an_early_update_until_its_frame():
    s = MapUpdateSchedule(1)
    s.keyframe_sent(5, 5)
    s.hold(_update(5))                              # local BA finished fast: arrived early
    assert s.missing(6) is None and s.take_due(6) == []   # frame 6 still sees the provisional map
    assert [u.keyframe_index for u in s.take_due(7)] == [5]


def test_lag_one_waits_for_a_late_update_and_keeps_later_ones_held():
    s = MapUpdateSchedule(1)
    s.keyframe_sent(5, 5)
    s.keyframe_sent(6, 6)                           # consecutive keyframes: two BAs queued
    assert s.missing(6) is None                     # nothing due yet: track frame 6 at once
    assert s.missing(7) == 5                        # slow BA: wait before frame 7
    s.hold(_update(5))
    s.hold(_update(6))                              # both arrived while waiting
    assert s.missing(7) is None
    assert [u.keyframe_index for u in s.take_due(7)] == [5]   # 6 is due only before frame 8
    assert s.missing(8) is None
    assert [u.keyframe_index for u in s.take_due(8)] == [6]


def test_a_repeated_update_after_a_loop_correction_is_applied_at_the_next_frame():
    s = MapUpdateSchedule(1)
    s.keyframe_sent(2, 2)
    s.hold(_update(2, "ba"))
    assert [u.tag for u in s.take_due(4)] == ["ba"]
    s.hold(_update(2, "loop"))                      # local mapping re-sends after a correction
    assert s.missing(5) is None
    assert [u.tag for u in s.take_due(5)] == ["loop"]


def test_bad_lag_is_rejected_with_the_key_named():
    with pytest.raises(ValueError, match="lag"):
        MapUpdateSchedule(-1)
    with pytest.raises(ConfigError, match="runtime.map_update_lag_frames"):
        RuntimeParams(map_update_lag_frames=9).validate()


def test_monocular_and_line_runs_wait_for_every_update():
    from canopy.frontend import TrackingParams
    from canopy.pipeline import effective_map_update_lag

    assert effective_map_update_lag(1, TrackingParams()) == 1
    assert effective_map_update_lag(1, TrackingParams(), sensor="mono") == 0
    assert effective_map_update_lag(2, TrackingParams(use_lines=True)) == 0
