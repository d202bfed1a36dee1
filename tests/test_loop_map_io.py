"""Maps that outlive a run: save, load, restore round trip; foreign files refused clearly."""
from __future__ import annotations

from dataclasses import replace

import msgpack
import numpy as np
import pytest

from canopy.backend import LocalMapper
from canopy.frontend import Tracker
from canopy.loop.map_io import load_map, map_from_mapper, restore_mapper, save_map
from canopy.sources import open_source
from shared.errors import InputError


@pytest.fixture(scope="module")
def built_map():
    src = open_source("kitti", max_frames=12)
    tracker, mapper = Tracker(src.calibration), LocalMapper(src.calibration)
    for i in range(len(src)):
        res = tracker.track(src.frame(i))
        if res.is_keyframe:
            tracker.apply_map_update(mapper.insert_keyframe(res.keyframe))
    assert len(mapper.keyframes) >= 3 and len(mapper.landmarks) > 100
    return src.calibration, mapper


def test_map_round_trip_restores_keyframes_landmarks_and_covisibility(tmp_path, built_map):
    calib, mapper = built_map
    data = map_from_mapper(mapper, vocabulary="orb_k10_L4.txt.gz")
    path = save_map(tmp_path / "map.canopy", data)
    back = load_map(path, calib)
    assert back.vocabulary == "orb_k10_L4.txt.gz" and back.calibration == calib
    for name in data.ARRAYS:
        np.testing.assert_array_equal(getattr(back, name), getattr(data, name), err_msg=name)
    assert len(back.covisibility) > 0
    restored = LocalMapper(calib)
    restore_mapper(back, restored)
    assert sorted(restored.keyframes) == sorted(mapper.keyframes)
    for k, rec in mapper.keyframes.items():
        np.testing.assert_array_equal(restored.keyframes[k].T_world_cam, rec.T_world_cam)
        np.testing.assert_array_equal(restored.keyframes[k].landmark, rec.landmark)
    for lid, lm in mapper.landmarks.items():
        np.testing.assert_array_equal(restored.landmarks[lid].position, lm.position)
        assert restored.landmarks[lid].obs == lm.obs
    # and the restored map saves to the same arrays again
    again = map_from_mapper(restored, vocabulary=back.vocabulary)
    for name in data.ARRAYS:
        np.testing.assert_array_equal(getattr(again, name), getattr(data, name), err_msg=name)


def test_map_from_another_calibration_version_or_format_is_refused(tmp_path, built_map):
    calib, mapper = built_map
    path = save_map(tmp_path / "map.canopy", map_from_mapper(mapper))
    with pytest.raises(InputError, match="another calibration.*fx"):
        load_map(path, replace(calib, fx=calib.fx * 1.01))
    doc = msgpack.unpackb(path.read_bytes(), raw=False)
    doc["version"] = 99
    (tmp_path / "v99.canopy").write_bytes(msgpack.packb(doc, use_bin_type=True))
    with pytest.raises(InputError, match="version 99 is not supported"):
        load_map(tmp_path / "v99.canopy", calib)
    (tmp_path / "junk.canopy").write_bytes(b"\x00\x01not a map")
    with pytest.raises(InputError, match="not a Canopy map file"):
        load_map(tmp_path / "junk.canopy", calib)
    with pytest.raises(InputError, match="map file not found"):
        load_map(tmp_path / "missing.canopy", calib)


def test_loop_keyframes_survive_save_and_load_and_old_files_load_without_them(tmp_path, built_map):
    """A closed loop's keyframes stay protected from culling in a run that extends a saved map
    (ORB-SLAM's SetNotErase, s17); a file written before the field existed loads with none, and a
    file naming a keyframe it does not hold is refused."""
    calib, mapper = built_map
    a, b = sorted(mapper.keyframes)[:2]
    mapper.keep_loop_edge(b, a)
    try:
        path = save_map(tmp_path / "map.canopy", map_from_mapper(mapper))
    finally:
        mapper.loop_keyframes.clear()
    restored = LocalMapper(calib)
    restore_mapper(load_map(path, calib), restored)
    assert restored.loop_keyframes == {a, b}
    doc = msgpack.unpackb(path.read_bytes(), raw=False)
    del doc["arrays"]["loop_keyframes"]                         # as s16's files were
    (tmp_path / "old.canopy").write_bytes(msgpack.packb(doc, use_bin_type=True))
    old = LocalMapper(calib)
    restore_mapper(load_map(tmp_path / "old.canopy", calib), old)
    assert old.loop_keyframes == set() and sorted(old.keyframes) == sorted(mapper.keyframes)
    doc["arrays"]["loop_keyframes"] = {"dtype": "<i8", "shape": [1], "data": np.int64(10**6).tobytes()}
    (tmp_path / "bad.canopy").write_bytes(msgpack.packb(doc, use_bin_type=True))
    with pytest.raises(InputError, match="loop keyframes it does not hold"):
        load_map(tmp_path / "bad.canopy", calib)
