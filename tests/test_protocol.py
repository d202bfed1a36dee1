"""Wire format: arrays as raw bytes, versioned envelopes, clear errors on garbage."""
import msgpack
import numpy as np
import pytest

from protocol.codec import PROTOCOL_VERSION, decode, encode, registered_kinds
from protocol.messages import ActorStats, FrameHandle, FramePose, MapSnapshot
from shared.errors import ProtocolError


def test_round_trip_keeps_arrays_exact():
    T = np.eye(4)
    T[:3, 3] = [1.5, -2.0, 3.25]
    msg = FramePose(index=7, timestamp=12.5, T_world_cam=T, status="ok", n_inliers=120, n_matches=150,
                    is_keyframe=True, ref_keyframe=7, T_ref_cam=np.eye(4), timings_ms={"orb": 6.1})
    back = decode(encode(msg))
    assert back == back  # dataclass equality with arrays is ambiguous; compare fields
    assert back.index == 7 and back.status == "ok" and back.timings_ms == {"orb": 6.1}
    np.testing.assert_array_equal(back.T_world_cam, T)
    assert back.T_world_cam.dtype == np.float64


@pytest.mark.parametrize("dtype", [np.uint8, np.int64, np.float32, np.float64])
def test_arrays_travel_as_one_block_of_bytes(dtype):
    pts = (np.arange(3000).reshape(1000, 3) % 251).astype(dtype)
    payload = encode(MapSnapshot(keyframe_indices=np.arange(3), keyframe_stamps=np.zeros(3),
                                 keyframe_poses=np.tile(np.eye(4), (3, 1, 1)), points=pts))
    # raw bytes, not element by element: the payload is barely larger than the array
    assert len(payload) < pts.nbytes + 700  # the envelope: field names and the other small arrays
    back = decode(payload)
    assert back.points.dtype == dtype and back.points.shape == (1000, 3)
    np.testing.assert_array_equal(back.points, pts)


def test_every_message_kind_is_registered_once():
    kinds = registered_kinds()
    assert len(kinds) == len(set(kinds))
    assert {"frame", "pose", "stats", "map_snapshot", "actor_error"} <= set(kinds)


@pytest.mark.parametrize("payload, fragment", [
    (b"\xc1\xc1garbage", "undecodable"),
    (msgpack.packb([1, 2, 3]), "not a Canopy envelope"),
    (msgpack.packb({"v": PROTOCOL_VERSION + 1, "k": "frame", "b": {}}), "protocol version"),
    (msgpack.packb({"v": PROTOCOL_VERSION, "k": "teleport", "b": {}}), "unknown message kind"),
    (msgpack.packb({"v": PROTOCOL_VERSION, "k": "frame", "b": {"index": 1}}), "missing field"),
    (msgpack.packb({"v": PROTOCOL_VERSION, "k": "frame_done", "b": {"index": 1, "bogus": 2}}), "unknown field"),
])
def test_malformed_messages_raise_protocol_error(payload, fragment):
    with pytest.raises(ProtocolError, match=fragment):
        decode(payload)


def test_truncated_array_payload_is_rejected():
    msg = FrameHandle(index=1, timestamp=0.0, ring="r", slot=0, generation=2, sent_at=0.0)
    good = encode(ActorStats(actor="a", pid=1, seq=0, messages=0, dropped=0, service_ms=np.ones(10, np.float32),
                             queue_ms=np.zeros(0, np.float32), cpu_percent=0.0, rss_mb=0.0, peak_rss_mb=0.0))
    assert decode(encode(msg)).slot == 0
    # chop bytes off the array inside the envelope: msgpack or our size check must refuse it
    with pytest.raises(ProtocolError):
        decode(good[:-20])


@pytest.mark.parametrize("kind, body, fragment", [
    ("frame", {"index": 1, "timestamp": 0.0, "ring": "r", "slot": "x", "generation": 1, "sent_at": 0.0},
     "'slot' must be an integer"),
    ("frame", {"index": 1, "timestamp": None, "ring": "r", "slot": 0, "generation": 1, "sent_at": 0.0},
     "'timestamp' must be a number"),
    ("frame", {"index": True, "timestamp": 0.0, "ring": "r", "slot": 0, "generation": 1, "sent_at": 0.0},
     "'index' must be an integer"),
    ("frame", {"index": 1, "timestamp": 0.0, "ring": 5, "slot": 0, "generation": 1, "sent_at": 0.0},
     "'ring' must be a string"),
    ("frame", {"index": 1, "timestamp": 0.0, "ring": "r", "slot": 0, "generation": 1, "sent_at": 0.0, "info": []},
     "'info' must be a mapping"),
    ("pose", {"index": 1, "timestamp": 0.0, "T_world_cam": [1, 2], "status": "ok", "n_inliers": 1, "n_matches": 1,
              "is_keyframe": False, "ref_keyframe": 0, "T_ref_cam": None}, "'T_world_cam' must be an array"),
])
def test_fields_of_the_wrong_type_are_rejected(kind, body, fragment):
    with pytest.raises(ProtocolError, match=fragment):
        decode(msgpack.packb({"v": PROTOCOL_VERSION, "k": kind, "b": body}))


def test_integer_for_a_float_field_is_widened():
    msg = decode(msgpack.packb({"v": PROTOCOL_VERSION, "k": "frame_done", "b": {"index": 3, "sent_at": 2}}))
    assert msg.sent_at == 2.0 and isinstance(msg.sent_at, float)


def _samples():
    T = np.eye(4)
    return [
        FrameHandle(index=4, timestamp=1.25, ring="canopy_raw", slot=3, generation=9, sent_at=5.5,
                    info={"method": "none", "enhance_ms": 1.5}),
        FramePose(index=7, timestamp=12.5, T_world_cam=T, status="ok", n_inliers=120, n_matches=150,
                  is_keyframe=True, ref_keyframe=7, T_ref_cam=T, timings_ms={"orb": 6.1}),
        ActorStats(actor="tracking", pid=12, seq=3, messages=40, dropped=1, service_ms=np.ones(6, np.float32),
                   queue_ms=np.zeros(2, np.float32), cpu_percent=55.0, rss_mb=120.0, peak_rss_mb=130.0,
                   extra={"ok": 3}),
        MapSnapshot(keyframe_indices=np.arange(3), keyframe_stamps=np.zeros(3),
                    keyframe_poses=np.tile(T, (3, 1, 1)), points=np.ones((20, 3), np.float32)),
    ]


def _check_types(msg):
    """Independent of the codec: every annotated scalar field holds its type."""
    import dataclasses
    import typing
    hints = typing.get_type_hints(type(msg))
    for f in dataclasses.fields(msg):
        v, tp = getattr(msg, f.name), hints[f.name]
        if tp is int:
            assert isinstance(v, int) and not isinstance(v, bool), (f.name, v)
        elif tp is float:
            assert isinstance(v, float), (f.name, v)
        elif tp is str:
            assert isinstance(v, str), (f.name, v)
        elif tp is bool:
            assert isinstance(v, bool), (f.name, v)
        elif tp is np.ndarray:
            assert isinstance(v, np.ndarray), (f.name, v)


def test_decoder_fuzz_raises_only_protocol_errors():
    """12 000 seeded mutations of real messages (bit flips, truncations, splices, random bytes and
    re-typed fields): every failure is a ProtocolError and every accepted message is well typed."""
    rng = np.random.default_rng(1234)
    good = [encode(m) for m in _samples()]
    junk_values = [None, "x", -1, 2**40, 1.5, True, [], {}, b"\x00", [1, "a"], {"a": None}]
    accepted = rejected = 0
    for n in range(12_000):
        base = bytearray(good[n % len(good)])
        how = n % 5
        if how == 0:  # flip a few bits
            for pos in rng.integers(0, len(base), size=int(rng.integers(1, 4))):
                base[pos] ^= 1 << int(rng.integers(0, 8))
            payload = bytes(base)
        elif how == 1:  # truncate
            payload = bytes(base[: int(rng.integers(0, len(base)))])
        elif how == 2:  # splice random bytes in
            pos = int(rng.integers(0, len(base)))
            payload = bytes(base[:pos]) + rng.bytes(int(rng.integers(1, 16))) + bytes(base[pos:])
        elif how == 3:  # random bytes
            payload = rng.bytes(int(rng.integers(0, 64)))
        else:  # a well-formed envelope with one field replaced by a value of another type
            env = msgpack.unpackb(bytes(base), raw=False, strict_map_key=False,
                                  ext_hook=lambda code, data: msgpack.ExtType(code, data))
            key = sorted(env["b"])[int(rng.integers(0, len(env["b"])))]
            env["b"][key] = junk_values[int(rng.integers(0, len(junk_values)))]
            payload = msgpack.packb(env, use_bin_type=True)
        try:
            msg = decode(payload)
        except ProtocolError:
            rejected += 1
            continue
        accepted += 1
        _check_types(msg)
    assert rejected > 6000 and accepted > 100, (accepted, rejected)
