"""Test configuration: persistent compilation cache, float32 by default, compiled programs released per module."""

import jax
import pytest

from gsjax.app.runtime.cache import enable_compilation_cache

enable_compilation_cache()
pytest_plugins = ["tests.support.compile_log"]  # GSJAX_COMPILE_LOG=DIR: every compilation, by test
# Start the backend now: an in-process `gsjax sweep` would otherwise choose this process's CPU device count.
jax.devices()


_MAPS_BEFORE_RELEASE = 20000


def _memory_maps() -> int:
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:  # not Linux
        return 0


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop the in-memory compiled programs after a test module once the process holds many memory maps. Each
    XLA:CPU executable holds some, and the whole suite in one process would otherwise approach the kernel's limit
    (vm.max_map_count, 65530), where the next compilation crashes. Later modules reload what they share from the
    persistent cache."""
    yield
    if _memory_maps() > _MAPS_BEFORE_RELEASE:
        jax.clear_caches()
