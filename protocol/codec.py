"""msgpack wire format shared by every actor.

Envelope: ``{"v": PROTOCOL_VERSION, "k": <message kind>, "b": {field: value}}``.
Numpy arrays travel as a msgpack extension holding dtype, shape and the raw
bytes (never element by element), so a 1000x32 descriptor block is one memcpy.
Decoding checks the version, the kind and the fields, and raises
``ProtocolError`` naming what is wrong, so a malformed message is reported
instead of crashing deep inside an actor.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import msgpack
import numpy as np

from shared.errors import ProtocolError

PROTOCOL_VERSION = 1
_NDARRAY_EXT = 1

_REGISTRY: dict[str, type] = {}


def message(kind: str):
    """Class decorator: register a dataclass as a wire message of ``kind``."""

    def wrap(cls):
        if kind in _REGISTRY:
            raise ValueError(f"message kind {kind!r} registered twice")
        cls = dataclasses.dataclass(cls)
        cls.KIND = kind
        _REGISTRY[kind] = cls
        return cls

    return wrap


def _default(obj: Any):
    if isinstance(obj, np.ndarray):
        arr = np.ascontiguousarray(obj)
        if arr.dtype.hasobject:
            raise ProtocolError(f"cannot send an object array of dtype {arr.dtype}")
        header = msgpack.packb([arr.dtype.str, list(arr.shape)])
        return msgpack.ExtType(_NDARRAY_EXT, header + arr.tobytes())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple):
        return list(obj)
    raise TypeError(f"cannot serialise {type(obj).__name__}")


def _ext_hook(code: int, data: bytes):
    if code != _NDARRAY_EXT:
        raise ProtocolError(f"unknown msgpack extension type {code}")
    unpacker = msgpack.Unpacker(raw=False)
    unpacker.feed(data)
    dtype_str, shape = next(unpacker)
    offset = unpacker.tell()
    dtype = np.dtype(dtype_str)
    count = int(np.prod(shape)) if shape else 1
    if len(data) - offset != count * dtype.itemsize:
        raise ProtocolError(f"array payload has {len(data) - offset} bytes, expected {count * dtype.itemsize}")
    # copy(): the received buffer is read-only and owned by the message.
    return np.frombuffer(data, dtype=dtype, count=count, offset=offset).reshape(shape).copy()


def encode(msg: Any) -> bytes:
    kind = getattr(type(msg), "KIND", None)
    if kind is None or not dataclasses.is_dataclass(msg):
        raise ProtocolError(f"{type(msg).__name__} is not a registered message")
    body = {f.name: getattr(msg, f.name) for f in dataclasses.fields(msg)}
    return msgpack.packb({"v": PROTOCOL_VERSION, "k": kind, "b": body}, default=_default, use_bin_type=True)


def decode(payload: bytes) -> Any:
    try:
        env = msgpack.unpackb(payload, ext_hook=_ext_hook, raw=False, strict_map_key=False)
    except ProtocolError:
        raise
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise ProtocolError(f"undecodable message ({type(exc).__name__}: {exc})") from None
    if not isinstance(env, dict) or not {"v", "k", "b"} <= env.keys():
        raise ProtocolError("message is not a Canopy envelope (needs v, k, b)")
    if env["v"] != PROTOCOL_VERSION:
        raise ProtocolError(f"protocol version {env['v']} received, this build speaks {PROTOCOL_VERSION}")
    cls = _REGISTRY.get(env["k"])
    if cls is None:
        raise ProtocolError(f"unknown message kind {env['k']!r}")
    body = env["b"]
    if not isinstance(body, dict):
        raise ProtocolError(f"{env['k']}: body is not a mapping")
    names = {f.name for f in dataclasses.fields(cls)}
    required = {f.name for f in dataclasses.fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    missing = required - body.keys()
    if missing:
        raise ProtocolError(f"{env['k']}: missing field(s) {sorted(missing)}")
    unknown = body.keys() - names
    if unknown:
        raise ProtocolError(f"{env['k']}: unknown field(s) {sorted(unknown)}")
    return cls(**body)


def registered_kinds() -> list[str]:
    return sorted(_REGISTRY)
