"""profile_frame times the step's real stages: every op of the one compiled program is attributed to the named
scope it came from, and the shares scale to the program's time."""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))
import profile_frame


def test_step_stages_attribute_each_op_to_its_named_scope():
    def program(x):
        with jax.named_scope("track"):  # far more work than the other stages
            y = x
            for _ in range(6):
                y = jnp.tanh(y @ x)
        with jax.named_scope("map"):
            z = jnp.sin(y[:8]).sum()
        return z + jnp.cos(x[0, 0])

    x = jnp.ones((256, 256), jnp.float32) / 256
    compiled = jax.jit(program).lower(x).compile()
    result = profile_frame.step_stages(compiled, (x,), repeats=2, step_ms=100.0)
    stages = result["stages_ms"]
    assert set(stages) == {"track", "densify", "map", "other"}
    assert abs(sum(stages.values()) - 100.0) < 1e-6  # shares of the step's time
    assert stages["densify"] == 0.0  # no op came from a scope the program lacks
    assert stages["track"] > 50.0 and stages["track"] > 5 * stages["map"]
    assert result["profiled_op_ms"] > 0
