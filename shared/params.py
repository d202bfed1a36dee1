"""Typed parameter objects loaded from YAML.

Every module defines one frozen dataclass of parameters with the papers'
values as defaults (Kimera-VIO's ``*Params`` habit). ``from_mapping`` builds
it from a YAML section and rejects unknown or badly typed keys with an error
that names the file and the key, so a typo never silently falls back to a
default.
"""
from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any, Mapping, TypeVar

import yaml

from shared.errors import ConfigError

P = TypeVar("P")


def _coerce(value: Any, annotation: Any, where: str) -> Any:
    origin = typing.get_origin(annotation)
    if annotation is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if annotation is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if annotation is bool and isinstance(value, bool):
        return value
    if annotation is str and isinstance(value, str):
        return value
    if origin is tuple and isinstance(value, (list, tuple)):
        args = typing.get_args(annotation)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], where) for v in value)
        if len(args) == len(value):
            return tuple(_coerce(v, a, where) for v, a in zip(value, args))
    if origin is typing.Union or str(origin) == "types.UnionType":
        for arg in typing.get_args(annotation):
            if arg is type(None) and value is None:
                return None
            try:
                return _coerce(value, arg, where)
            except ConfigError:
                continue
    if dataclasses.is_dataclass(annotation) and isinstance(value, Mapping):
        return params_from_mapping(annotation, value, where)
    raise ConfigError(where, f"expected {getattr(annotation, '__name__', annotation)}, got {value!r}")


def params_from_mapping(cls: type[P], mapping: Mapping[str, Any] | None, source: str = "<config>") -> P:
    """Build the dataclass ``cls`` from ``mapping``; missing keys keep defaults."""
    if mapping is not None and not isinstance(mapping, Mapping):
        raise ConfigError(source, f"{cls.__name__} parameters must be a mapping of name: value, "
                                  f"got a {type(mapping).__name__}")
    mapping = dict(mapping or {})
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(mapping) - names)
    if unknown:
        raise ConfigError(source, f"unknown parameter(s) for {cls.__name__}: {', '.join(unknown)}")
    kwargs = {k: _coerce(v, hints[k], f"{source}: {cls.__name__}.{k}") for k, v in mapping.items()}
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        validate()
    return obj


def load_yaml(path: str | Path) -> dict:
    """Read a YAML file into a dict, naming the file in any error."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, "config file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(path, f"not valid YAML ({exc})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(path, "top level must be a mapping of sections")
    return data


def params_to_dict(obj: Any) -> dict:
    return dataclasses.asdict(obj)
