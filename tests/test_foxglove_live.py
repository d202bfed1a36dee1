"""``--foxglove``: a WebSocket client (the ``websockets`` package, speaking Foxglove's protocol)
connected to the live view receives poses, images and the map, in Foxglove's protobuf schemas.

Needs the ``foxglove`` extra (``pip install '.[foxglove]'``; ``.[test]`` installs it too)."""
from __future__ import annotations

import json
import socket
import struct
import threading
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("foxglove", reason="foxglove-sdk not installed: pip install '.[foxglove]' (part of .[test])")
ws_client = pytest.importorskip("websockets.sync.client",
                                reason="websockets not installed: pip install '.[foxglove]' (part of .[test])")

from actors.foxglove_live import EVENTS_TOPIC, FoxgloveLive, parse_foxglove_address  # noqa: E402
from canopy.recording import IMAGE_TOPIC, LINES_TOPIC, POINTS_TOPIC, POSE_TOPIC, TF_TOPIC  # noqa: E402
from protocol.messages import FramePose, LoopResult, MapSnapshot  # noqa: E402
from shared.errors import ConfigError  # noqa: E402

SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks (the app offers it)


# -- a minimal protobuf reader: enough to check the values that were sent -------------------------

def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if b < 0x80:
            return value, i


def proto_fields(buf: bytes) -> dict[int, list]:
    """field number -> values (int for varint, bytes for length-delimited, float for fixed64/32)."""
    out: dict[int, list] = {}
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = struct.unpack_from("<d", buf, i)[0], i + 8
        elif wire == 2:
            n, i = _varint(buf, i)
            value, i = buf[i:i + n], i + n
        elif wire == 5:
            value, i = struct.unpack_from("<f", buf, i)[0], i + 4
        else:
            raise ValueError(f"wire type {wire}")
        out.setdefault(field, []).append(value)
    return out


def pose_position(payload: bytes) -> np.ndarray:
    """foxglove.PoseInFrame: pose = 3, Pose.position = 1, Vector3 x/y/z = 1/2/3 (doubles)."""
    vec = proto_fields(proto_fields(proto_fields(payload)[3][0])[1][0])
    return np.array([vec.get(k, [0.0])[0] for k in (1, 2, 3)])


# -- a Foxglove WebSocket client ------------------------------------------------------------------

class Client(threading.Thread):
    """Connects (retrying until ``deadline_s``), subscribes to every advertised channel, and collects
    message payloads per topic."""

    def __init__(self, port: int, deadline_s: float = 120.0):
        super().__init__(daemon=True)
        self.port, self.deadline = port, time.monotonic() + deadline_s
        self.topics: dict[int, str] = {}        # channel id -> topic
        self.schemas: dict[str, str] = {}       # topic -> schema name
        self.received: dict[str, list[bytes]] = {}
        self.subscribed = threading.Event()
        self.stop = threading.Event()

    def run(self) -> None:
        ws = None
        while ws is None and time.monotonic() < self.deadline and not self.stop.is_set():
            try:
                ws = ws_client.connect(f"ws://127.0.0.1:{self.port}", subprotocols=[SUBPROTOCOL], open_timeout=2)
            except OSError:
                time.sleep(0.05)
            except Exception:
                time.sleep(0.05)
        if ws is None:
            return
        with ws:
            while not self.stop.is_set() and time.monotonic() < self.deadline:
                try:
                    msg = ws.recv(timeout=0.2)
                except TimeoutError:
                    continue
                except Exception:
                    return  # server closed: the run ended
                if isinstance(msg, str):
                    op = json.loads(msg)
                    if op.get("op") == "advertise":
                        subs = []
                        for ch in op["channels"]:
                            self.topics[ch["id"]] = ch["topic"]
                            self.schemas[ch["topic"]] = ch["schemaName"]
                            subs.append({"id": ch["id"], "channelId": ch["id"]})
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        if POSE_TOPIC in self.schemas:
                            self.subscribed.set()
                elif msg[0] == 1:  # message data: opcode, subscription id u32, log time u64, payload
                    sub_id, _ = struct.unpack_from("<IQ", msg, 1)
                    self.received.setdefault(self.topics.get(sub_id, "?"), []).append(bytes(msg[13:]))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(pred, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


def _pose(index: int, t: np.ndarray, status: str = "ok") -> FramePose:
    T = np.eye(4)
    T[:3, 3] = t
    return FramePose(index=index, timestamp=100.0 + 0.05 * index, T_world_cam=T, status=status, n_inliers=50,
                     n_matches=80, is_keyframe=False, ref_keyframe=0, T_ref_cam=np.eye(4))


def test_client_receives_pose_image_map_and_loop_event():
    rng = np.random.default_rng(0)
    image = (rng.random((480, 752)) * 255).astype(np.uint8)
    image[100:300, 200:500] = 255  # a bright box that must survive JPEG + downscaling
    live = FoxgloveLive("127.0.0.1", 0, frames=lambda index: image if index == 1 else None, run_id="test-run")
    client = Client(live.port, deadline_s=30)
    client.start()
    try:
        assert client.subscribed.wait(10), "no advertise / subscribe within 10 s"
        assert _wait(lambda: live.pose_channel.has_sinks() and live.points_channel.has_sinks()
                     and live.image_channel.has_sinks())
        live(_pose(0, np.array([1.0, 2.0, 3.0]), status="lost"))  # a lost frame has no pose: not sent
        live(_pose(1, np.array([0.5, -1.25, 4.0])))
        points = rng.normal(size=(321, 3)).astype(np.float32)
        segments = np.array([[[0, 0, 1], [1, 0, 1]], [[0, 1, 2], [0, 2, 2.5]]], np.float32)
        live(MapSnapshot(keyframe_indices=np.array([0]), keyframe_stamps=np.array([100.0]),
                         keyframe_poses=np.eye(4)[None], points=points, lines=segments))
        live(LoopResult(keyframe_index=40, closed=True, candidate=3, n_inliers=77, loops=1))
        assert _wait(lambda: all(client.received.get(t) for t in (POSE_TOPIC, TF_TOPIC, IMAGE_TOPIC, POINTS_TOPIC,
                                                                   LINES_TOPIC))
                     and len(client.received.get(EVENTS_TOPIC, [])) >= 1)
    finally:
        client.stop.set()
        live.close()
        client.join(5)
    assert client.schemas[POSE_TOPIC] == "foxglove.PoseInFrame"
    assert client.schemas[TF_TOPIC] == "foxglove.FrameTransform"
    assert client.schemas[IMAGE_TOPIC] == "foxglove.CompressedImage"
    assert client.schemas[POINTS_TOPIC] == "foxglove.PointCloud"
    assert client.schemas[EVENTS_TOPIC] == "foxglove.Log"
    assert client.schemas[LINES_TOPIC] == "foxglove.SceneUpdate"
    # one pose (the lost frame was skipped), with the position that was sent
    assert len(client.received[POSE_TOPIC]) == 1
    np.testing.assert_allclose(pose_position(client.received[POSE_TOPIC][0]), [0.5, -1.25, 4.0])
    # the image: a downscaled JPEG that still shows the bright box
    jpeg = next(v for v in proto_fields(client.received[IMAGE_TOPIC][0]).values()
                if isinstance(v[0], bytes) and v[0][:2] == b"\xff\xd8")[0]
    preview = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert preview.shape == (240, 376)
    assert preview[60:140, 110:240].mean() > 240 and preview[180:, :].mean() < 160
    # the map: every point, float32 x y z
    data = [v for v in proto_fields(client.received[POINTS_TOPIC][0]).values()
            if isinstance(v[0], bytes) and len(v[0]) == points.nbytes]
    assert data and np.array_equal(np.frombuffer(data[0][0], "<f4").reshape(-1, 3), points)
    assert any(b"loop closed: keyframe 40 <-> 3" in e for e in client.received[EVENTS_TOPIC])
    # the lines: SceneUpdate.entities -> SceneEntity.lines -> LinePrimitive.points -> Point3 x, y, z
    num = {m: proto_field_numbers("foxglove.SceneUpdate", m) for m in ("SceneUpdate", "SceneEntity",
                                                                      "LinePrimitive", "Point3")}
    entity = proto_fields(proto_fields(client.received[LINES_TOPIC][0])[num["SceneUpdate"]["entities"]][0])
    prim = proto_fields(entity[num["SceneEntity"]["lines"]][0])
    ends = [[proto_fields(p).get(num["Point3"][k], [0.0])[0] for k in "xyz"]
            for p in prim[num["LinePrimitive"]["points"]]]
    np.testing.assert_allclose(ends, segments.reshape(-1, 3))


def test_address_errors_are_one_line():
    with pytest.raises(ConfigError, match="loopback"):
        parse_foxglove_address("0.0.0.0:8765")
    with pytest.raises(ConfigError, match="HOST:PORT"):
        parse_foxglove_address("8765")
    with pytest.raises(ConfigError, match="unknown host"):
        parse_foxglove_address("no-such-host.invalid:8765")
    assert parse_foxglove_address("localhost:9000")[1] == 9000
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        with pytest.raises(ConfigError, match="cannot serve there"):
            FoxgloveLive("127.0.0.1", busy.getsockname()[1])


def test_launch_foxglove_serves_a_real_run(tmp_path):
    """The real multi-process run on the bundled EuRoC snippet: a client connected to --foxglove
    receives poses that match the run's trajectory, enhanced images and the map."""
    from canopy.app import run_slam

    port = _free_port()
    client = Client(port)
    client.start()  # connects as soon as the launcher serves (before any actor starts)
    try:
        res = run_slam("euroc", max_frames=25, clock="lockstep", out=str(tmp_path / "run"), progress=False,
                       foxglove=f"127.0.0.1:{port}", loop=False)
    finally:
        client.stop.set()
        client.join(10)
    assert res.outcome.ok, res.outcome.reason
    poses = client.received.get(POSE_TOPIC, [])
    assert len(poses) >= 15, f"only {len(poses)} poses received"
    assert client.received.get(IMAGE_TOPIC), "no image received"
    assert client.received.get(POINTS_TOPIC), "no map received"
    # the last pose streamed is the last tracked frame's pose as tracked (before final BA)
    last = np.loadtxt(tmp_path / "run" / "trajectory.tum")[-1, 1:4]
    assert np.linalg.norm(pose_position(poses[-1]) - last) < 0.05


def proto_field_numbers(schema_name: str, message: str | None = None) -> dict[str, int]:
    """{field name: number} of a Foxglove message (``message``, default the schema's own), read
    from the SDK's protobuf FileDescriptorSet of ``schema_name`` (FileDescriptorSet.file = 1;
    FileDescriptorProto package = 2, message_type = 4; DescriptorProto name = 1, field = 2;
    FieldDescriptorProto name = 1, number = 3)."""
    import foxglove.messages

    package, name = schema_name.split(".")
    message = message or name
    data = getattr(foxglove.messages, name).get_schema().data
    for file in proto_fields(data)[1]:
        f = proto_fields(file)
        if f.get(2, [b""])[0].decode() != package:
            continue
        for msg in f.get(4, []):
            m = proto_fields(msg)
            if m[1][0].decode() == message:
                return {proto_fields(fd)[1][0].decode(): proto_fields(fd)[3][0] for fd in m.get(2, [])}
    raise AssertionError(f"{package}.{message} not in the SDK's schema {schema_name}")


def test_recording_schemas_match_the_sdk():
    """The .mcap recording writes JSON under hand-written JSON Schemas (canopy.recording) named after
    Foxglove's; every field they declare must exist under that name in the SDK's own schema, so the
    recording and the live view show the same messages the same way."""
    from canopy.recording import SCHEMAS

    checked = 0
    for name, schema in SCHEMAS.items():
        if not name.startswith("foxglove."):
            continue
        assert set(schema["properties"]) <= set(proto_field_numbers(name)), name
        checked += 1
    assert checked >= 4


def test_launch_refuses_a_bad_foxglove_address_or_a_missing_sdk_in_one_line(capsys, monkeypatch):
    import launch

    assert launch.main(["--foxglove", "0.0.0.0:8765", "--max-frames", "2", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "loopback" in err[0]
    monkeypatch.setitem(__import__("sys").modules, "foxglove", None)  # as if the extra were not installed
    assert launch.main(["--foxglove", "--max-frames", "2", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install" in err[0] and "foxglove" in err[0]


def test_garbage_on_the_foxglove_socket_does_not_grow_the_launcher_or_stop_the_view(caplog):
    """10 000 random messages (text and binary, up to 2 kB) on the WebSocket the launcher exposes:
    the server drops them (or the connection), its memory stays bounded, other clients are served."""
    import psutil

    live = FoxgloveLive("127.0.0.1", 0, run_id="fuzz")
    rss0 = psutil.Process().memory_info().rss
    rng = np.random.default_rng(3)
    sent = 0
    while sent < 10_000:
        try:
            with ws_client.connect(f"ws://127.0.0.1:{live.port}", subprotocols=[SUBPROTOCOL]) as bad:
                while sent < 10_000:
                    n = int(rng.integers(0, 2048))
                    bad.send(rng.bytes(n) if rng.random() < 0.5 else rng.bytes(n).hex()[:n])
                    sent += 1
        except Exception:
            sent += 1  # the server closed the connection on garbage: knock again with the rest
    client = Client(live.port, deadline_s=30)
    client.start()
    try:
        assert client.subscribed.wait(10)
        assert _wait(lambda: live.pose_channel.has_sinks())
        live(_pose(1, np.array([1.0, 2.0, 3.0])))
        assert _wait(lambda: bool(client.received.get(POSE_TOPIC)))
    finally:
        client.stop.set()
        live.close()
        client.join(5)
    assert psutil.Process().memory_info().rss - rss0 < 100 * 2**20
    # the SDK's error per bad message is logged for the first few only
    from actors.foxglove_live import CLIENT_LOGGER, MAX_CLIENT_LOG_RECORDS
    logged = [r for r in caplog.records if r.name == CLIENT_LOGGER]
    assert 1 <= len(logged) <= MAX_CLIENT_LOG_RECORDS
