"""Config fields declared once: each field's unit, whether it is static (a shape, a mode, a flag: part of the
compiled program) or traced (a value users sweep), its bounds and how it follows the image width, as dataclass
field metadata (:func:`param`). The configs' validation (:func:`check_fields`), :func:`gsjax.slam.presets.at_width`,
the command line's overrides and their messages, and the generated config reference (``gsjax config
--reference``) all read them from here; a field's meaning is its entry in its class's ``Attributes:`` docstring
(:func:`field_docs`).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterator, Mapping
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

_T = TypeVar("_T")


def is_checkable(value: Any) -> bool:
    """Whether ``value`` (a number, an array or a pytree of them) can be checked now: every leaf a concrete number
    or array, none a tracer (under jit/vmap/grad), and at least one leaf (not a placeholder JAX puts in a pytree,
    such as ``None`` in a vmap ``in_axes`` tree), and no array sharded over other processes (checked where built)."""
    leaves = jax.tree_util.tree_leaves(value)
    return bool(leaves) and all(
        isinstance(leaf, (int, float, np.ndarray, np.generic, jax.Array)) and not isinstance(leaf, jax.core.Tracer)
        and (not isinstance(leaf, jax.Array) or leaf.is_fully_addressable)
        for leaf in leaves
    )

# How a field follows the image width (gsjax.slam.presets.at_width): "width" scales with it (a length in pixels),
# "footprint" inversely (a bound measured in pixel footprints, e.g. pruning's size bound), None stays.
SCALINGS = ("width", "footprint", None)


@dataclasses.dataclass(frozen=True)
class FieldSpec:
    """One config field's declaration (read from ``dataclasses.Field.metadata["spec"]``).

    Attributes:
      unit: what the value measures: ``px``, ``px^2``, ``m``, ``cm``, ``deg``, ``rad``, ``count``, ``weight``,
        ``ratio``, ``flag``, ``choice``, ... (shown in messages and the reference).
      static: part of the compiled program's structure (shapes, modes, flags); traced fields are pytree leaves that
        ``jax.vmap`` sweeps without recompiling.
      low, high: bounds (None: unbounded); low_open, high_open: whether the bound itself is excluded.
      choices: the allowed values of a mode.
      scaling: how the value follows the image width (:data:`SCALINGS`).
      unit_by: (sibling field, {its value: unit}): the unit depends on a mode (CB-KNN's alpha is px or a fraction).
    """

    unit: str
    static: bool = False
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple | None = None
    scaling: str | None = None
    unit_by: tuple[str, Mapping[str, str]] | None = None

    def unit_of(self, owner: Any) -> str:
        """The field's unit in ``owner`` (resolving :attr:`unit_by`)."""
        if self.unit_by is None:
            return self.unit
        sibling, units = self.unit_by
        return units[getattr(owner, sibling)]

    def scaled(self, value: Any, owner: Any, ratio: float) -> Any:
        """``value`` for a width ``ratio`` (new / given) times the one it is given for (:attr:`scaling`)."""
        if self.scaling == "width" and self.unit_of(owner) == "px":
            return value * ratio
        if self.scaling == "footprint":
            return value / ratio
        return value

    def bounds_text(self) -> str:
        """The bounds as text, e.g. ``>= 0 and <= 1`` ('' when unbounded)."""
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.low_open else '>='} {_number(self.low)}")
        if self.high is not None:
            parts.append(f"{'<' if self.high_open else '<='} {_number(self.high)}")
        return " and ".join(parts)

    def describe(self, kind: str) -> str:
        """What a valid value is, in words (the messages' ``must be ...``), for a field of type ``kind``."""
        if self.choices is not None:
            return f"one of {', '.join(map(str, self.choices))}"
        if kind == "bool":
            return "true or false"
        bounds = self.bounds_text()
        what = {"int": "an int", "tuple": "a tuple of ints"}.get(kind, "a finite number")
        unit = f" ({self.unit})" if self.unit not in ("count", "ratio", "weight", "flag", "choice") else ""
        return f"{what}{' ' + bounds if bounds else ''}{unit}"


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(value)


def param(default: _T, unit: str, *, static: bool = False, low: float | None = None, high: float | None = None,
          low_open: bool = False, high_open: bool = False, choices: tuple | None = None, scaling: str | None = "auto",
          unit_by: tuple[str, Mapping[str, str]] | None = None) -> _T:
    """A config field with its declaration (:class:`FieldSpec`). ``scaling`` ``"auto"``: a traced field in ``px``
    scales with the width (a static one in px is a shape and stays); ``static=True`` makes it part of the treedef
    (``jax.tree_util.register_dataclass`` reads the same metadata)."""
    if scaling == "auto":
        px = unit == "px" or (unit_by is not None and "px" in unit_by[1].values())
        scaling = "width" if px and not static else None
    if scaling not in SCALINGS:
        raise ValueError(f"scaling must be one of {SCALINGS}, got {scaling!r}")
    spec = FieldSpec(unit, static, low, high, low_open, high_open, choices, scaling, unit_by)
    return dataclasses.field(default=default, metadata=dict(static=static, spec=spec))


def derived(default: Any = None) -> Any:
    """A static field computed from the others (e.g. ``SlamConfig.caps`` from the iteration counts): part of the tree
    structure, but not a setting: :func:`walk`, :func:`rescale`, the overrides and ``config.json`` leave it out."""
    return dataclasses.field(default=default, metadata=dict(static=True, derived=True))


def is_derived(field: dataclasses.Field) -> bool:
    """Whether ``field`` is :func:`derived`."""
    return bool(field.metadata.get("derived"))


def settings_fields(config: Any) -> list[dataclasses.Field]:
    """The fields of ``config`` a user sets (every field but the :func:`derived` ones)."""
    return [f for f in dataclasses.fields(config) if not is_derived(f)]


def required(unit: str, **declaration: Any) -> Any:
    """A field without a default (e.g. a camera's focal length), declared as :func:`param` declares one."""
    return param(dataclasses.MISSING, unit, **declaration)


def spec_of(field: dataclasses.Field) -> FieldSpec | None:
    """The declaration of ``field``; None for a nested config (a section)."""
    return field.metadata.get("spec")


def kind_of(field: dataclasses.Field) -> str:
    """The field's value type as declared: ``int``, ``float``, ``bool``, ``str``, ``tuple`` or a section's class."""
    kind = field.type if isinstance(field.type, str) else getattr(field.type, "__name__", str(field.type))
    return kind.split("[")[0]  # "float | None" stays whole: None is then a valid value


def check_fields(config: Any, owner: str) -> None:
    """Check every declared field of ``config`` against its :class:`FieldSpec`; ValueError naming ``owner.field``.

    Traced values are checked when they are concrete (numbers or arrays, elementwise); under ``jit``/``vmap`` they
    are tracers or placeholders and were checked when built."""
    for field in dataclasses.fields(config):
        spec = spec_of(field)
        if spec is not None:
            check_value(f"{owner}.{field.name}", getattr(config, field.name), spec, kind_of(field))


def check_value(name: str, value: Any, spec: FieldSpec, kind: str) -> None:
    """Check one value of a field of type ``kind`` against ``spec``; ValueError ``name must be ..., got ...``."""
    if not _valid(value, spec, kind):
        raise ValueError(f"{name} must be {spec.describe(kind)}, got {value!r}")


def _valid(value: Any, spec: FieldSpec, kind: str) -> bool:
    if value is None:
        return "None" in kind  # an optional field (``float | None``) left unset
    kind = kind.split(" |")[0]
    if spec.choices is not None:
        if isinstance(value, str) or spec.static:
            return isinstance(value, str) and value in spec.choices
        if not is_checkable(value):
            return True  # a traced choice's index: checked when built
        index = np.asarray(value)
        return np.issubdtype(index.dtype, np.integer) and bool(np.all((index >= 0) & (index < len(spec.choices))))
    if kind == "tuple":
        return isinstance(value, tuple) and all(_is_int(v) and _within(float(v), spec) for v in value)
    if spec.static or isinstance(value, (bool, int, float, str)):
        if kind == "bool":
            return isinstance(value, (bool, np.bool_))
        if kind == "int" and not _is_int(value):
            return False
        if kind == "str":
            return isinstance(value, str)
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            return False
        return math.isfinite(float(value)) and _within(float(value), spec)
    if not is_checkable(value):
        return True  # traced, or a placeholder JAX puts in a pytree (e.g. vmap's in_axes): checked when built
    array = np.asarray(value)
    if kind == "bool":
        return array.dtype == np.bool_
    if array.dtype == np.bool_ or not np.issubdtype(array.dtype, np.number):
        return False
    v = array.astype(np.float64)
    if kind == "int" and np.any(v % 1):
        return False
    return bool(np.isfinite(v).all()) and _within(v, spec)


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _within(v, spec: FieldSpec) -> bool:
    ok = True
    if spec.low is not None:
        ok = ok and bool(np.all(v > spec.low if spec.low_open else v >= spec.low))
    if spec.high is not None:
        ok = ok and bool(np.all(v < spec.high if spec.high_open else v <= spec.high))
    return ok


@dataclasses.dataclass(frozen=True)
class FieldEntry:
    """One leaf field of a config tree, as :func:`walk` yields it: its dotted ``path``, the ``owner`` instance that
    holds it, its ``field`` and ``spec``."""

    path: str
    owner: Any
    field: dataclasses.Field
    spec: FieldSpec | None

    @property
    def value(self) -> Any:
        return getattr(self.owner, self.field.name)


def walk(config: Any, prefix: str = "") -> Iterator[FieldEntry]:
    """Every leaf field of a nested config, depth first in declaration order (sections are descended into; derived
    fields left out)."""
    for field in settings_fields(config):
        value = getattr(config, field.name)
        path = f"{prefix}{field.name}"
        if dataclasses.is_dataclass(value) and spec_of(field) is None:
            yield from walk(value, path + ".")
        else:
            yield FieldEntry(path, config, field, spec_of(field))


def rescale(config: _T, ratio: float) -> _T:
    """``config`` with every field that follows the width (:attr:`FieldSpec.scaling`) scaled for a width ``ratio``
    times the one its values are given for; the same object when ``ratio`` is 1."""
    if ratio == 1:
        return config
    changes: dict[str, Any] = {}
    for field in settings_fields(config):
        value = getattr(config, field.name)
        spec = spec_of(field)
        if spec is None and dataclasses.is_dataclass(value):
            scaled = rescale(value, ratio)
            if scaled is not value:
                changes[field.name] = scaled
        elif spec is not None and spec.scaled(1.0, config, ratio) != 1.0:
            changes[field.name] = spec.scaled(value, config, ratio)
    return dataclasses.replace(config, **changes) if changes else config  # type: ignore[type-var]


_ENTRY = re.compile(r"^(\s+)([A-Za-z_][\w]*(?:,\s*[A-Za-z_]\w*)*):\s?(.*)$")


def field_docs(cls: type) -> dict[str, str]:
    """Each field's meaning from the ``Attributes:`` section of ``cls``'s docstring (Google style: ``name: text``,
    or ``a, b: text`` for fields documented together; continuation lines indented deeper)."""
    lines = (cls.__doc__ or "").splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == "Attributes:")
    except StopIteration:
        return {}
    docs: dict[str, str] = {}
    names: list[str] = []
    indent = None
    for line in lines[start + 1:]:
        if not line.strip():
            if names:
                continue
            break
        match = _ENTRY.match(line)
        depth = len(line) - len(line.lstrip())
        if match and (indent is None or depth == indent):
            indent = depth
            names = [n.strip() for n in match.group(2).split(",")]
            for n in names:
                docs[n] = match.group(3).strip()
        elif indent is not None and depth > indent and names:
            for n in names:
                docs[n] += " " + line.strip()
        else:
            break
    return docs


def choice_is(value: Any, name: str, choices: tuple) -> bool | jax.Array:
    """Whether a choice field's ``value`` is ``name``: a bool for a name given as text, a bool array for a traced
    choice (its index into ``choices``, as :func:`register_config` flattens it).

    Args:
      value: the field's value: one of ``choices``, or an int index into them (concrete or traced, any shape).
      name: the choice to test for, one of ``choices``.
      choices: the field's choices (:attr:`FieldSpec.choices`).

    Returns:
      ``value == name`` as a Python bool, or as a bool array of ``value``'s shape.
    """
    if isinstance(value, str):
        return value == name
    return jnp.asarray(value) == choices.index(name)


def _traced_choices(cls: type) -> dict[str, tuple]:
    return {f.name: spec.choices for f in dataclasses.fields(cls)
            if (spec := spec_of(f)) is not None and spec.choices is not None and not spec.static}


def _encode_choice(value: Any, choices: tuple | None) -> Any:
    return np.int32(choices.index(value)) if choices is not None and isinstance(value, str) else value


def _decode_choice(value: Any, choices: tuple | None) -> Any:
    if choices is None or isinstance(value, str) or not is_checkable(value) or np.ndim(value) != 0:
        return value
    index = int(np.asarray(value))
    return choices[index] if 0 <= index < len(choices) else value  # out of range: check_fields names it


def register_config(cls: type[_T]) -> type[_T]:
    """``jax.tree_util.register_dataclass`` for a config class whose traced choice fields (declared with ``choices``
    and not ``static``, e.g. CB-KNN's mode) are flattened to their index, an int32 leaf, so that configs differing in
    that choice share one compiled program. A concrete index unflattens back to its name; a traced or stacked one
    stays an index (test it with :func:`choice_is`). Static fields are part of the tree structure, as with
    ``register_dataclass``.

    Args:
      cls: a frozen dataclass of :func:`param` fields.

    Returns:
      ``cls``, registered as a pytree node.
    """
    fields = dataclasses.fields(cls)  # type: ignore[arg-type]
    data = [f.name for f in fields if not f.metadata.get("static")]
    meta = [f.name for f in fields if f.metadata.get("static")]
    choices = _traced_choices(cls)

    def flatten_with_keys(obj):
        children = [(jax.tree_util.GetAttrKey(n), _encode_choice(getattr(obj, n), choices.get(n))) for n in data]
        return children, tuple(getattr(obj, n) for n in meta)

    def flatten(obj):
        children, aux = flatten_with_keys(obj)
        return [child for _, child in children], aux

    def unflatten(aux, children):
        kwargs = dict(zip(meta, aux))
        kwargs.update({n: _decode_choice(c, choices.get(n)) for n, c in zip(data, children)})
        return cls(**kwargs)

    jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)
    return cls
