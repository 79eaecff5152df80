"""Configs as text: overrides by dotted field name (``--tracking.iters 60``) and the JSON round trip of
``config.json`` / ``metrics.json``. No config is ever executed as code: values are parsed as the field's type and
validated by the config classes."""

from __future__ import annotations

import dataclasses
import typing
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from gsjax.slam.config import SlamConfig

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

_Config = TypeVar("_Config", bound="DataclassInstance")


def _convert(text: str, current, path: str):
    """Parse ``text`` as the type of the field's current value."""
    try:
        if isinstance(current, bool):
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError
        if isinstance(current, (int, np.integer)):
            return int(text)
        if isinstance(current, (float, np.floating)):
            return float(text)
        if isinstance(current, tuple):
            return tuple(int(x) for x in text.split(",") if x.strip())
        if isinstance(current, str):
            return text
    except ValueError:
        pass
    raise ValueError(f"--{path}: cannot read {text!r} as {type(current).__name__}")


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
    names = {f.name for f in dataclasses.fields(obj)}
    if parts[0] not in names:
        raise ValueError(f"--{path}: unknown field {parts[0]!r} (fields: {', '.join(sorted(names))})")
    current = getattr(obj, parts[0])
    value = _set_path(current, parts[1:], text, path) if len(parts) > 1 else _convert(text, current, path)
    try:
        return dataclasses.replace(obj, **{parts[0]: value})
    except ValueError as err:
        raise ValueError(f"--{path}: {err}") from None


def config_to_dict(config: DataclassInstance) -> dict[str, Any]:
    """A JSON-friendly nested dict of a config (for ``config.json``)."""
    out: dict[str, Any] = {}
    for field in dataclasses.fields(config):
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
    base = SlamConfig() if base is None else base
    kwargs: dict[str, Any] = {}
    hints = typing.get_type_hints(type(base))
    for key, value in data.items():
        if key not in hints:
            raise ValueError(f"config: unknown field {key!r}")
        current = getattr(base, key)
        if dataclasses.is_dataclass(current):
            kwargs[key] = config_from_dict(value, current)
        elif isinstance(current, tuple):
            kwargs[key] = tuple(value)
        else:
            kwargs[key] = value
    return dataclasses.replace(base, **kwargs)
