"""Test configuration: persistent compilation cache, float32 by default."""

from gsjax.compilation_cache import enable_compilation_cache

enable_compilation_cache()
