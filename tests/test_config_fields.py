"""Config fields declared once (issue 38, part 3): every field has a unit, a meaning and bounds; static-ness in the
declaration is what JAX sees; validation, width scaling, old names and the generated reference come from it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.config.fields import check_fields, field_docs, param, rescale, spec_of, walk
from gsjax.config.names import PRESETS
from gsjax.config.text import apply_overrides
from gsjax.slam.config import CONFIG_CLASSES, SlamConfig
from gsjax.slam.presets import PRESET_WIDTH, preset

REFERENCE = Path(__file__).resolve().parents[1] / "docs" / "reference" / "config.md"


def undeclared(config) -> list[str]:
    """The leaf fields of ``config`` without a unit, or without a meaning in their class's docstring."""
    missing = []
    for entry in walk(config):
        if entry.spec is None or not entry.spec.unit.strip():
            missing.append(f"{entry.path}: no unit")
        if not field_docs(type(entry.owner)).get(entry.field.name):
            missing.append(f"{entry.path}: no meaning")
    return missing


def test_every_config_field_has_a_unit_and_a_meaning():
    assert undeclared(SlamConfig()) == []
    # Every config class is reached from SlamConfig (so the reference and the checks cover it).
    reached = {type(entry.owner) for entry in walk(SlamConfig())}
    assert reached == set(CONFIG_CLASSES)
    # The camera and the synthetic scene declare theirs the same way (and check themselves from them).
    from gsjax.camera import make_intrinsics
    from gsjax.data.synthetic import SyntheticConfig

    assert undeclared(make_intrinsics(40.0, 40.0, 19.5, 14.5, 30, 40)) == []
    assert undeclared(SyntheticConfig()) == []
    with pytest.raises(ValueError, match=r"intrinsics\.fy must be a finite number > 0 \(px\), got 0\.0"):
        make_intrinsics(40.0, 0.0, 19.5, 14.5, 30, 40)
    with pytest.raises(ValueError, match=r"synthetic\.num_frames must be an int >= 1 \(frames\), got 0"):
        SyntheticConfig(num_frames=0)


def test_a_field_without_a_unit_or_a_meaning_is_found():
    @dataclasses.dataclass(frozen=True)
    class Probe:
        """A probe.

        Attributes:
          declared: documented and declared.
          bare: documented, no declaration.
        """

        declared: float = param(1.0, "m")
        bare: float = 2.0
        quiet: int = param(3, "count")

    assert undeclared(Probe()) == ["bare: no unit", "quiet: no meaning"]


def test_the_declared_static_flag_is_what_jax_sees():
    """Changing a static field's value changes the treedef (a new program); a traced one is a leaf."""
    base = apply_overrides(preset("cpu"), {"tracking.blur.radius_px": "4"})  # coarse.iters needs it
    structure = jax.tree_util.tree_structure(base)
    leaves = len(jax.tree_util.tree_leaves(base))
    traced = [e.path for e in walk(base) if not e.spec.static]
    assert len(traced) == leaves  # every traced field is one leaf, nothing else is
    for entry in walk(base):
        if entry.spec.static:
            changed = apply_overrides(base, {entry.path: _another(entry)})
            assert jax.tree_util.tree_structure(changed) != structure, entry.path


def _another(entry) -> str:
    """A valid value of a static field other than its current one, as command-line text."""
    value, spec = entry.value, entry.spec
    if spec.choices:
        return next(c for c in spec.choices if c != value)
    if isinstance(value, bool):
        return str(not value)
    if isinstance(value, tuple):
        return "1"
    if spec.high is not None:
        return str(value / 2)
    return str(value + 1)


@pytest.mark.parametrize("value, message", [
    (-1.0, r"probe\.length must be a finite number >= 0 \(m\), got -1\.0"),
    (float("nan"), r"probe\.length must be a finite number >= 0 \(m\)"),
    (np.array([0.5, -0.1]), r"probe\.length must be a finite number >= 0 \(m\)"),  # a batch of configs, elementwise
    (True, r"probe\.length must be a finite number"),
])
def test_checks_come_from_the_declaration_and_name_the_field(value, message):
    @dataclasses.dataclass(frozen=True)
    class Probe:
        length: float = param(1.0, "m", low=0.0)
        count: int = param(2, "count", static=True, low=1, high=5)
        mode: str = param("a", "choice", static=True, choices=("a", "b"))
        frame: int = param(1, "frame", low=1)

        def __post_init__(self):
            check_fields(self, "probe")

    with pytest.raises(ValueError, match=message):
        Probe(length=value)
    for bad, text in ((0, "an int >= 1 and <= 5"), (6, "an int >= 1 and <= 5"), (2.0, "an int"), (True, "an int")):
        with pytest.raises(ValueError, match=f"probe.count must be {text}"):
            Probe(count=bad)
    with pytest.raises(ValueError, match="probe.mode must be one of a, b, got 'c'"):
        Probe(mode="c")
    with pytest.raises(ValueError, match="probe.frame must be an int >= 1"):
        Probe(frame=np.array([1.0, 2.5]))
    Probe(length=np.array([0.0, 3.0], np.float32), frame=np.array([1, 4]))  # batches of valid values pass
    # Under jit the values are tracers: checked where the config was built, not again.
    assert float(jax.jit(lambda x: Probe(length=x).length)(jnp.float32(-1.0))) == -1.0


def test_every_field_in_px_follows_the_width_unless_it_is_a_shape():
    """``at_width`` scales what the declarations say: every traced px field by the width ratio, the pruning bound
    against it, and nothing else; a new px field would scale without a list to add it to."""
    cpu = preset("cpu")
    doubled = rescale(cpu, 2.0)
    for before, after in zip(walk(cpu), walk(doubled)):
        spec = before.spec
        px = spec.unit_of(before.owner) == "px" and not spec.static
        expected = before.value * 2 if px else before.value / 2 if spec.scaling == "footprint" else before.value
        assert after.value == expected, before.path
        if spec.unit == "px" and spec.static:
            assert spec.scaling is None, before.path  # a shape (tile, cell, filter radius) stays

    @dataclasses.dataclass(frozen=True)
    class Probe:
        margin: float = param(3.0, "px")
        radius: int = param(4, "px", static=True)
        near: float = param(0.2, "m")

    assert rescale(Probe(), 0.5) == Probe(margin=1.5)
    assert rescale(Probe(), 1) is not None and rescale(cpu, 1.0) is cpu


def test_the_docstrings_parse_into_one_meaning_per_field():
    from gsjax.slam.tracking_config import DivergenceGuard

    docs = field_docs(DivergenceGuard)
    assert list(docs) == ["max_step_m", "max_step_deg", "loss_jump", "retry_lr_scale"]
    assert docs["retry_lr_scale"].endswith("keeps the prediction.)")  # continuation lines joined
    assert spec_of(dataclasses.fields(DivergenceGuard)[0]).unit == "m"


def test_the_committed_config_reference_is_the_generated_one():
    from gsjax.app.config_reference import config_reference

    text = config_reference()
    assert REFERENCE.read_text(encoding="utf-8") == text, "run `make config-reference` and commit the result"
    for entry in walk(SlamConfig()):
        assert f"| `{entry.path}` |" in text
    for name in PRESETS:
        assert f"{name} {PRESET_WIDTH[name]} px" in text
