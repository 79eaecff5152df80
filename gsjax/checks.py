"""Small helpers shared by the value checks of configs and render arguments."""

from __future__ import annotations

import jax
import numpy as np


def is_checkable(value) -> bool:
    """A concrete number or array whose value can be checked now: not a tracer (under jit/vmap/grad), nor a
    placeholder JAX puts in a pytree (such as ``None`` in a vmap ``in_axes`` tree)."""
    return isinstance(value, (int, float, np.ndarray, np.generic, jax.Array)) and not isinstance(
        value, jax.core.Tracer
    )
