"""Small helpers shared by the value checks of configs and render arguments."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np


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
