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
import math
import types
import typing
from typing import Any, Callable

import msgpack
import numpy as np

from shared.errors import ProtocolError

PROTOCOL_VERSION = 1
_NDARRAY_EXT = 1

_REGISTRY: dict[str, type] = {}
# kind -> {field name: check(value) -> value (possibly coerced), raising ProtocolError}
_FIELD_CHECKS: dict[str, dict[str, Callable[[Any], Any]]] = {}
# A msgpack-ext array must not claim more elements than this (a corrupt shape must not allocate GBs).
MAX_ARRAY_ELEMENTS = 1 << 28


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
    try:
        unpacker = msgpack.Unpacker(raw=False)
        unpacker.feed(data)
        dtype_str, shape = next(unpacker)
        offset = unpacker.tell()
        dtype = np.dtype(dtype_str)
        if not isinstance(shape, list) or not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0
                                                  for d in shape):
            raise ProtocolError(f"array shape {shape!r} is not a list of non-negative integers")
    except ProtocolError:
        raise
    except Exception as exc:  # garbage header: msgpack, numpy and unpacking errors alike
        raise ProtocolError(f"malformed array header ({type(exc).__name__}: {exc})") from None
    if dtype.hasobject or dtype.itemsize == 0:
        raise ProtocolError(f"array dtype {dtype} cannot travel as raw bytes")
    count = math.prod(shape)
    if count > MAX_ARRAY_ELEMENTS:
        raise ProtocolError(f"array shape {shape} is too large")
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
    """Message from wire bytes. Every failure, whatever its cause, is a ``ProtocolError``."""
    try:
        return _decode(payload)
    except ProtocolError:
        raise
    except Exception as exc:  # msgpack and numpy raise several unrelated types on garbage
        raise ProtocolError(f"undecodable message ({type(exc).__name__}: {exc})") from None


def _decode(payload: bytes) -> Any:
    env = msgpack.unpackb(payload, ext_hook=_ext_hook, raw=False, strict_map_key=False)
    if not isinstance(env, dict) or not {"v", "k", "b"} <= env.keys():
        raise ProtocolError("message is not a Canopy envelope (needs v, k, b)")
    if env["v"] != PROTOCOL_VERSION:
        raise ProtocolError(f"protocol version {env['v']!r} received, this build speaks {PROTOCOL_VERSION}")
    kind = env["k"]
    cls = _REGISTRY.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise ProtocolError(f"unknown message kind {kind!r}")
    body = env["b"]
    if not isinstance(body, dict) or not all(isinstance(k, str) for k in body):
        raise ProtocolError(f"{kind}: body is not a mapping of field names")
    names = {f.name for f in dataclasses.fields(cls)}
    required = {f.name for f in dataclasses.fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
    missing = required - body.keys()
    if missing:
        raise ProtocolError(f"{kind}: missing field(s) {sorted(missing)}")
    unknown = body.keys() - names
    if unknown:
        raise ProtocolError(f"{kind}: unknown field(s) {sorted(unknown)}")
    checks = _field_checks(cls)
    return cls(**{name: checks[name](value) if name in checks else value for name, value in body.items()})


# -- field type checks -----------------------------------------------------------------------------

def _type_check(tp, kind: str, name: str) -> Callable[[Any], Any] | None:
    """A checker for one annotated field type; None when the type is not checked."""
    def fail(value, expected: str):
        raise ProtocolError(f"{kind}: field '{name}' must be {expected}, got {type(value).__name__} "
                            f"{_short(value)}")

    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        allow_none = len(options) < len(typing.get_args(tp))
        inner = _type_check(options[0], kind, name) if len(options) == 1 else None
        if inner is None:
            return None

        def check_optional(v):
            return None if (v is None and allow_none) else inner(v)
        return check_optional
    base = origin or tp
    if base is bool:
        return lambda v: v if isinstance(v, bool) else fail(v, "a bool")
    if base is int:
        return lambda v: v if isinstance(v, int) and not isinstance(v, bool) else fail(v, "an integer")
    if base is float:
        # msgpack sends 3.0 as an int when the sender had an int: accept and widen.
        return lambda v: (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                          else fail(v, "a number"))
    if base is str:
        return lambda v: v if isinstance(v, str) else fail(v, "a string")
    if base is np.ndarray:
        return lambda v: v if isinstance(v, np.ndarray) else fail(v, "an array")
    if base is dict:
        return lambda v: v if isinstance(v, dict) else fail(v, "a mapping")
    if base in (list, tuple):
        return lambda v: v if isinstance(v, list) else fail(v, "a list")
    return None


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _field_checks(cls) -> dict[str, Callable[[Any], Any]]:
    checks = _FIELD_CHECKS.get(cls.KIND)
    if checks is None:
        hints = typing.get_type_hints(cls)
        checks = {}
        for f in dataclasses.fields(cls):
            check = _type_check(hints.get(f.name), cls.KIND, f.name)
            if check is not None:
                checks[f.name] = check
        _FIELD_CHECKS[cls.KIND] = checks
    return checks


def registered_kinds() -> list[str]:
    return sorted(_REGISTRY)
