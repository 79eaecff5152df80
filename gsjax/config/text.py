"""Configs as text: overrides by dotted field name (``--tracking.iters 60``) and the JSON round trip of
``config.json`` / ``metrics.json``. No config is ever executed as code: values are parsed as the field's declared
type and validated by the config classes (:mod:`gsjax.config.fields`).
"""

from __future__ import annotations

import dataclasses
import typing
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from gsjax.config.fields import kind_of, settings_fields, spec_of
from gsjax.slam.config import SlamConfig

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

_Config = TypeVar("_Config", bound="DataclassInstance")


def _convert(text: str, kind: str, path: str):
    """Parse ``text`` as a value of the field's declared type ``kind``."""
    try:
        if kind == "bool":
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if kind == "int":
            return int(text)
        if kind == "float":
            return float(text)
        if kind == "tuple":
            return tuple(int(x) for x in text.split(",") if x.strip())
        if kind == "str":
            return text
    except ValueError:
        pass
    raise ValueError(f"--{path}: cannot read {text!r} as {kind}")


def apply_overrides(config: _Config, overrides: dict[str, str]) -> _Config:
    """A copy of ``config`` with dotted field names set from strings, e.g. ``{"tracking.iters": "60"}``.

    Raises ValueError naming the field for unknown names and unreadable or invalid values.
    """
    for path, text in overrides.items():
        config = _set_path(config, path.split("."), text, path)
    return config


def _set_path(obj, parts: list[str], text: str, path: str):
    if not dataclasses.is_dataclass(obj):
        raise ValueError(f"--{path}: {parts[0]!r} is not a config section")
    fields = {f.name: f for f in settings_fields(obj)}
    if parts[0] not in fields:
        raise ValueError(f"--{path}: unknown field {parts[0]!r} (fields: {', '.join(sorted(fields))})")
    field = fields[parts[0]]
    if len(parts) > 1:
        value = _set_path(getattr(obj, parts[0]), parts[1:], text, path)
    elif spec_of(field) is None:
        raise ValueError(f"--{path}: cannot read {text!r} as {kind_of(field)} (a config section: set its fields, "
                         f"--{path}.NAME)")
    else:
        value = _convert(text, kind_of(field), path)
    try:
        return dataclasses.replace(obj, **{parts[0]: value})
    except ValueError as err:
        raise ValueError(f"--{path}: {err}") from None


def config_to_dict(config: DataclassInstance) -> dict[str, Any]:
    """A JSON-friendly nested dict of a config (for ``config.json``)."""
    out: dict[str, Any] = {}
    for field in settings_fields(config):
        value = getattr(config, field.name)
        if dataclasses.is_dataclass(value):
            out[field.name] = config_to_dict(value)
        elif isinstance(value, tuple):
            out[field.name] = list(value)
        else:
            arr = np.asarray(value)
            out[field.name] = arr.item() if arr.ndim == 0 else arr.tolist()
    return out


@typing.overload
def config_from_dict(data: dict[str, Any], base: None = None) -> SlamConfig: ...


@typing.overload
def config_from_dict(data: dict[str, Any], base: _Config) -> _Config: ...


def config_from_dict(data: dict[str, Any], base: DataclassInstance | None = None) -> DataclassInstance:
    """Inverse of :func:`config_to_dict` (unknown keys are errors)."""
    return _from_dict(data, SlamConfig() if base is None else base)


def canonical_config_dict(data: dict[str, Any] | None) -> dict[str, Any] | None:
    """``data`` as :func:`config_to_dict` writes the same config (every field present, JSON's lists read as the
    fields' tuples), for comparing records (resume); None stays None."""
    return None if data is None else config_to_dict(config_from_dict(data))


def _from_dict(data: dict[str, Any], base: DataclassInstance) -> DataclassInstance:
    kwargs: dict[str, Any] = {}
    hints = {f.name for f in settings_fields(base)}
    for key, value in data.items():
        if key not in hints:
            raise ValueError(f"config: unknown field {key!r}")
        current = getattr(base, key)
        if dataclasses.is_dataclass(current):
            kwargs[key] = _from_dict(value, current)
        elif isinstance(current, tuple):
            kwargs[key] = tuple(value)
        else:
            kwargs[key] = value
    return dataclasses.replace(base, **kwargs)
