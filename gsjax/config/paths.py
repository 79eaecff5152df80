"""Config fields by dotted name as typed values: read one, set one, and the traced float fields that have a
derivative (what hypergradients and ``gsjax tune`` take: :mod:`gsjax.slam.hypergrad`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, TypeVar

from gsjax.config.fields import FieldEntry, kind_of, walk

_Config = TypeVar("_Config")


def field_entry(config: Any, path: str) -> FieldEntry:
    """The leaf field ``path`` (e.g. ``"cbknn.params.alpha"``) of ``config``.

    Args:
      config: a config dataclass (a :class:`gsjax.slam.config.SlamConfig`).
      path: the dotted name, as the command line's overrides spell it.

    Returns:
      Its :class:`gsjax.config.fields.FieldEntry` (value, owner, declaration).

    Raises:
      ValueError: naming ``path``, when no such field exists.
    """
    for entry in walk(config):
        if entry.path == path:
            return entry
    raise ValueError(f"unknown field {path!r} (fields are dotted names such as tracking.lr_trans or "
                     f"cbknn.params.alpha: see `gsjax run --help`)")


def differentiable_entry(config: Any, path: str) -> FieldEntry:
    """The field ``path`` of ``config``, checked to have a derivative: a traced float field.

    Args:
      config: a config dataclass.
      path: the dotted name.

    Returns:
      Its :class:`gsjax.config.fields.FieldEntry`.

    Raises:
      ValueError: naming ``path``, for an unknown field, a static one (part of the compiled program: a shape, a mode,
        a flag) or one that is not a float (an iteration count, a switch, a choice: no derivative).
    """
    entry = field_entry(config, path)
    spec, kind = entry.spec, kind_of(entry.field)
    if spec is None or spec.static:
        raise ValueError(f"{path} is static (part of the compiled program: a shape, a mode or a flag): it has no "
                         "derivative; only traced float fields can be differentiated or tuned")
    if kind != "float":
        what = {"int": "an integer", "bool": "a switch", "str": "a choice"}.get(kind, f"a {kind}")
        raise ValueError(f"{path} is {what} ({spec.unit}): it has no derivative; only traced float fields can be "
                         "differentiated or tuned")
    return entry


def differentiable_fields(config: Any) -> list[str]:
    """The dotted names of every traced float field of ``config`` (those :func:`differentiable_entry` accepts).

    Args:
      config: a config dataclass.

    Returns:
      The names, in declaration order.
    """
    return [e.path for e in walk(config)
            if e.spec is not None and not e.spec.static and kind_of(e.field) == "float"]


def replace_path(config: _Config, path: str, value: Any) -> _Config:
    """``config`` with the field ``path`` set to ``value`` (``dataclasses.replace`` section by section, so each
    section's checks run; a traced value is checked when it is concrete).

    Args:
      config: a config dataclass.
      path: the dotted name of a leaf field.
      value: its new value (a number, or an array or a tracer for a traced field).

    Returns:
      The new config.

    Raises:
      ValueError: naming ``path``, for an unknown field or a value its declaration refuses.
    """
    field_entry(config, path)
    head, _, rest = path.partition(".")
    if not rest:
        return dataclasses.replace(config, **{head: value})  # type: ignore[type-var]
    return dataclasses.replace(config, **{head: replace_path(getattr(config, head), rest, value)})  # type: ignore


def replace_paths(config: _Config, values: Mapping[str, Any]) -> _Config:
    """``config`` with each field of ``values`` set, in order (:func:`replace_path`).

    Args:
      config: a config dataclass.
      values: ``{dotted name: value}``.

    Returns:
      The new config.
    """
    for path, value in values.items():
        config = replace_path(config, path, value)
    return config
