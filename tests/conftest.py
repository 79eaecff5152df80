"""Test configuration: persistent compilation cache, float32 by default, compiled programs released per module."""

import jax
import pytest

from gsjax.compilation_cache import enable_compilation_cache

enable_compilation_cache()


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop every in-memory compiled program after each test module. Each XLA:CPU executable holds memory maps,
    and the whole suite in one process would otherwise approach the kernel's limit (vm.max_map_count, 65530),
    where the next compilation crashes. Later modules reload what they share from the persistent cache."""
    yield
    jax.clear_caches()
