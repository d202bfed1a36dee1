"""MCAP recording: Foxglove schemas, exact round trips, bad input, the recorder actor's handling,
and a recording whose writer is SIGKILLed still reads back."""
import base64
import json
import os
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from actors.recorder import RecorderActor
from canopy.recording import McapRecorder, read_messages
from protocol.messages import ActorStats, EndOfStream, FrameHandle, FramePose, MapSnapshot
from shared.errors import ConfigError, InputError
from shared.geometry import quat_wxyz_to_rot
from shared.ring import FrameRing

REPO = Path(__file__).resolve().parents[1]
T0 = 1403715273.262142  # an EuRoC-like stamp: nanosecond log times must survive it


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    R, _ = cv2.Rodrigues(axis * angle)
    return R


def _pose(i):
    T = np.eye(4)
    T[:3, :3] = _rot([0.3, -1.0, 0.2 + i], 0.1 + 0.7 * i)
    T[:3, 3] = [0.5 * i, -0.25 * i, 1.0 + 0.125 * i]
    return T


def _image(i, h=48, w=64):
    rng = np.random.default_rng(i)
    return rng.integers(0, 256, (h, w), dtype=np.uint8)


def _read_all(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs = [(ch.topic, sc.name, m.log_time, json.loads(m.data)) for sc, ch, m in reader.iter_messages()]
    return summary, msgs


@pytest.fixture
def recording(tmp_path):
    path = tmp_path / "out" / "run.mcap"   # parent folder is created
    rng = np.random.default_rng(7)
    points = rng.normal(size=(500, 3)).astype(np.float32)
    segments = rng.normal(size=(4, 2, 3))
    with McapRecorder(path) as rec:
        for i in range(3):
            rec.add_pose(T0 + 0.05 * i, _pose(i))
            rec.add_image(T0 + 0.05 * i, _image(i))
        rec.add_point_cloud(T0 + 0.1, points)
        rec.add_lines(T0 + 0.1, segments)
        rec.add_stats(T0 + 0.1, "tracking", {"service_ms_p50": np.float32(12.5), "lost": np.int64(2),
                                             "bad": float("nan"), "extra": {"ok": 3}})
    return path, points, segments


def test_topics_schemas_and_counts(recording):
    path, _, _ = recording
    summary, msgs = _read_all(path)
    channels = {ch.topic: summary.schemas[ch.schema_id] for ch in summary.channels.values()}
    assert {t: s.name for t, s in channels.items()} == {
        "/camera/pose": "foxglove.PoseInFrame", "/tf": "foxglove.FrameTransform",
        "/camera/left/image": "foxglove.CompressedImage", "/map/points": "foxglove.PointCloud",
        "/map/lines": "foxglove.SceneUpdate", "/stats/tracking": "canopy.ActorStats"}
    for ch in summary.channels.values():
        assert ch.message_encoding == "json"
        schema = summary.schemas[ch.schema_id]
        assert schema.encoding == "jsonschema"
        assert json.loads(schema.data)["title"] == schema.name
    assert Counter(t for t, *_ in msgs) == {"/camera/pose": 3, "/tf": 3, "/camera/left/image": 3,
                                           "/map/points": 1, "/map/lines": 1, "/stats/tracking": 1}
    assert summary.statistics.message_count == 12


def test_pose_round_trips(recording):
    path, _, _ = recording
    _, msgs = _read_all(path)
    poses = [(t, m) for topic, _, t, m in msgs if topic == "/camera/pose"]
    tfs = [m for topic, _, _, m in msgs if topic == "/tf"]
    for i, ((log_time, msg), tf) in enumerate(zip(poses, tfs)):
        ns = int(round((T0 + 0.05 * i) * 1e9))
        assert log_time == ns
        assert msg["timestamp"] == {"sec": ns // 10**9, "nsec": ns % 10**9}
        assert msg["frame_id"] == "world"
        p, q = msg["pose"]["position"], msg["pose"]["orientation"]
        T = _pose(i)
        np.testing.assert_allclose([p["x"], p["y"], p["z"]], T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(quat_wxyz_to_rot([q["w"], q["x"], q["y"], q["z"]]), T[:3, :3], atol=1e-9)
        assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("world", "camera")
        assert tf["translation"] == p and tf["rotation"] == q


def test_image_decodes_to_same_pixels(recording):
    path, _, _ = recording
    images = [m for topic, _, _, m in read_messages(path, ["/camera/left/image"])]
    assert len(images) == 3
    for i, msg in enumerate(images):
        assert msg["format"] == "png" and msg["frame_id"] == "camera"
        img = cv2.imdecode(np.frombuffer(base64.b64decode(msg["data"]), np.uint8), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(img, _image(i))


def test_point_cloud_and_lines_decode_exactly(recording):
    path, points, segments = recording
    _, msgs = _read_all(path)
    cloud = next(m for topic, _, _, m in msgs if topic == "/map/points")
    assert cloud["point_stride"] == 12 and cloud["frame_id"] == "world"
    assert cloud["fields"] == [{"name": "x", "offset": 0, "type": 7}, {"name": "y", "offset": 4, "type": 7},
                               {"name": "z", "offset": 8, "type": 7}]
    decoded = np.frombuffer(base64.b64decode(cloud["data"]), "<f4").reshape(-1, 3)
    np.testing.assert_array_equal(decoded, points)
    scene = next(m for topic, _, _, m in msgs if topic == "/map/lines")
    (entity,) = scene["entities"]
    (line,) = entity["lines"]
    assert line["type"] == 2  # LINE_LIST: pairs of points are segments
    got = np.array([[p["x"], p["y"], p["z"]] for p in line["points"]]).reshape(-1, 2, 3)
    np.testing.assert_allclose(got, segments, atol=1e-12)
    stats = next(m for topic, _, _, m in msgs if topic == "/stats/tracking")
    assert stats["actor"] == "tracking" and stats["service_ms_p50"] == 12.5 and stats["lost"] == 2
    assert stats["bad"] is None and stats["extra"] == {"ok": 3}  # NaN is not JSON: null


def test_bad_input_errors(tmp_path):
    with McapRecorder(tmp_path / "bad.mcap") as rec:
        with pytest.raises(InputError, match="4, 4"):
            rec.add_pose(1.0, np.eye(3))
        with pytest.raises(InputError, match="NaN"):
            rec.add_pose(1.0, np.full((4, 4), np.nan))
        with pytest.raises(InputError, match="rotation"):
            rec.add_pose(1.0, np.diag([2.0, 1, 1, 1]))
        with pytest.raises(InputError, match="timestamp"):
            rec.add_pose(-1.0, np.eye(4))
        with pytest.raises(InputError, match="uint8"):
            rec.add_image(1.0, np.zeros((4, 4), np.float32))
        with pytest.raises(InputError, match=r"\(H, W\)"):
            rec.add_image(1.0, np.zeros((4, 4, 2), np.uint8))
        with pytest.raises(InputError, match=r"\(N, 3\)"):
            rec.add_point_cloud(1.0, np.zeros((5, 2), np.float32))
        with pytest.raises(InputError, match=r"\(L, 2, 3\)"):
            rec.add_lines(1.0, np.zeros((5, 3)))
        with pytest.raises(InputError, match="actor name"):
            rec.add_stats(1.0, "a b", {})
        with pytest.raises(InputError, match="already carries"):
            rec.add_pose(1.0, np.eye(4))
            rec.add_image(1.0, _image(0), topic="/camera/pose")
        assert rec.add_point_cloud(1.0, np.array([[1, 2, 3], [np.nan, 0, 0]], np.float32)) == 1
    with pytest.raises(InputError, match="closed"):
        rec.add_pose(1.0, np.eye(4))
    rec.close()  # idempotent
    with pytest.raises(InputError, match=r"\.mcap"):
        McapRecorder(tmp_path / "run.txt")
    (tmp_path / "dir.mcap").mkdir()
    with pytest.raises(InputError, match="folder"):
        McapRecorder(tmp_path / "dir.mcap")
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match="not a folder"):
        McapRecorder(tmp_path / "file" / "run.mcap")


def test_recording_of_a_killed_writer_still_reads(tmp_path):
    path = tmp_path / "killed.mcap"
    code = (f"import os, signal, numpy as np\n"
            f"from canopy.recording import McapRecorder\n"
            f"rec = McapRecorder({str(path)!r}, flush_period_s=0.0)\n"
            f"for i in range(10):\n"
            f"    rec.add_pose({T0} + i, np.eye(4))\n"
            f"os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, timeout=60)
    assert proc.returncode == -9, proc.stderr.decode()
    with open(path, "rb") as f, pytest.raises(Exception):
        make_reader(f).get_summary()  # no footer: the indexed reader gives up ...
    msgs = list(read_messages(path))  # ... reading through still works
    assert Counter(t for t, *_ in msgs) == {"/camera/pose": 10, "/tf": 10}
    # and a file cut in the middle of a record stops cleanly at the last whole one
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:-7])
    assert 0 < len(list(read_messages(cut))) <= 20
    # the launcher repairs both into files the indexed reader opens, keeping every whole message
    from canopy.recording import repair_recording
    for broken, expected in ((path, 20), (cut, len(list(read_messages(cut))))):
        assert repair_recording(broken) == expected
        with open(broken, "rb") as f:
            reader = make_reader(f)
            assert reader.get_summary() is not None
            assert sum(1 for _ in reader.iter_messages()) == expected
        assert repair_recording(broken) is None  # finished files are left alone


# --- the recorder actor, driven directly (no sockets) -------------------------------------------

@pytest.fixture
def ring():
    r = FrameRing.create(f"canopy_rec_test_{os.getpid()}", n_slots=3, height=48, width=64)
    yield r
    r.close()
    r.unlink()


def _handle(ring, i, slot, gen):
    return FrameHandle(index=i, timestamp=T0 + 0.05 * i, ring=ring.name, slot=slot, generation=gen,
                       sent_at=time.time())


def _frame_pose(i, T=None):
    return FramePose(index=i, timestamp=T0 + 0.05 * i, T_world_cam=_pose(i) if T is None else T, status="ok",
                     n_inliers=100, n_matches=120, is_keyframe=False, ref_keyframe=0, T_ref_cam=np.eye(4))


def test_recorder_actor_handles_messages(tmp_path, ring):
    path = tmp_path / "actor.mcap"
    actor = RecorderActor({"path": str(path), "ring": ring.name, "image_every": 2, "end_of_streams": 2})
    actor.open()
    results = []
    handles = []
    for i in range(5):
        slot, gen = ring.write(i, T0 + 0.05 * i, [_image(i), _image(100 + i)])
        handles.append(_handle(ring, i, slot, gen))
        results.append(actor.record(handles[-1]))
        results.append(actor.record(_frame_pose(i)))
    # a handle whose slot was written over before the recorder read it is dropped, not fatal
    stale = handles[0]
    results.append(actor.record(_handle(ring, 6, stale.slot, stale.generation)))
    results.append(actor.record(_frame_pose(7, T=np.full((4, 4), np.nan))))  # lost tracking: skipped
    results.append(actor.record(MapSnapshot(
        keyframe_indices=np.array([0, 4]), keyframe_stamps=np.array([T0, T0 + 0.2]),
        keyframe_poses=np.stack([np.eye(4)] * 2), points=np.arange(12, dtype=np.float32).reshape(4, 3),
        lines=np.ones((2, 2, 3), np.float32))))
    results.append(actor.record(ActorStats(
        actor="tracking", pid=1, seq=0, messages=5, dropped=0, service_ms=np.array([10, 20, 30], np.float32),
        queue_ms=np.zeros(0, np.float32), cpu_percent=95.0, rss_mb=100.0, peak_rss_mb=120.0, extra={"ok": 5})))
    assert actor.record(EndOfStream(n_frames=5)) == "end_of_stream" and not actor.finished
    assert actor.record(EndOfStream(n_frames=5)) == "end_of_stream" and actor.finished
    actor.close()
    actor.close()  # idempotent

    assert results.count("images") == 3 and results.count("images_skipped") == 2  # frames 0, 2, 4
    assert results.count("dropped") == 1 and actor.dropped == 1
    assert actor.counts["poses"] == 5 and actor.counts["poses_skipped"] == 1
    assert actor.counts["maps"] == 1 and actor.counts["stats"] == 1

    summary, msgs = _read_all(path)
    by_topic = Counter(t for t, *_ in msgs)
    assert by_topic == {"/camera/left/image": 3, "/camera/pose": 5, "/tf": 5, "/map/points": 1,
                        "/map/lines": 1, "/stats/tracking": 1}
    images = [(t, m) for topic, _, t, m in msgs if topic == "/camera/left/image"]
    for (log_time, msg), i in zip(images, (0, 2, 4)):
        assert log_time == int(round((T0 + 0.05 * i) * 1e9))
        img = cv2.imdecode(np.frombuffer(base64.b64decode(msg["data"]), np.uint8), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(img, _image(i))
    cloud_time, cloud = next((t, m) for topic, _, t, m in msgs if topic == "/map/points")
    assert cloud_time == int(round((T0 + 0.2) * 1e9))  # newest keyframe's time
    np.testing.assert_array_equal(np.frombuffer(base64.b64decode(cloud["data"]), "<f4").reshape(-1, 3),
                                  np.arange(12, dtype=np.float32).reshape(4, 3))
    stats = next(m for topic, _, _, m in msgs if topic == "/stats/tracking")
    assert stats["service_ms_p50"] == 20.0 and stats["service_ms_max"] == 30.0 and stats["extra"] == {"ok": 5}


def test_idle_recorder_actor_flushes_to_disk(tmp_path):
    """What a SIGKILL would leave: the file as it is on disk before close()."""
    path = tmp_path / "idle.mcap"
    actor = RecorderActor({"path": str(path), "flush_period_s": 3600.0})
    actor.open()
    assert actor.next_tick_s() is None  # nothing written, nothing to do
    actor.record(_frame_pose(0))
    assert 3500 < actor.next_tick_s() <= 3600
    assert list(read_messages(path)) == []  # still in the writer's open chunk
    actor.recorder.flush_period_s = 0.0  # ... an hour later
    assert actor.next_tick_s() == 0.0
    actor.on_tick(ctx=None)
    assert actor.next_tick_s() is None
    assert Counter(t for t, *_ in read_messages(path)) == {"/camera/pose": 1, "/tf": 1}
    actor.close()


def test_recorder_actor_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="path"):
        RecorderActor({})
    with pytest.raises(ConfigError, match="image_every"):
        RecorderActor({"path": str(tmp_path / "a.mcap"), "image_every": 0})
    actor = RecorderActor({"path": str(tmp_path / "a.mcap"), "ring": "canopy_no_such_ring"})
    with pytest.raises(InputError, match="ring not found"):
        actor.open()
    actor.close()
