"""JAX's persistent compilation cache, shared by the CLI, the tests and the experiments.

Compiled XLA programs are stored under ``$GSJAX_CACHE_DIR`` (default: ``$XDG_CACHE_HOME/gsjax/jax`` or
``~/.cache/gsjax/jax``), so a second run of the same shapes skips compilation; the SLAM program's exported form
in it (``exported/``, :mod:`gsjax.app.runtime.programs`), so a second run also skips tracing it.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import jax

_exported = None  # this process's ExportedPrograms, once the cache is enabled


def cache_dir() -> Path:
    """Directory of the persistent compilation cache (not created)."""
    if "GSJAX_CACHE_DIR" in os.environ:
        return Path(os.environ["GSJAX_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "gsjax" / "jax"


def enable_compilation_cache() -> Path:
    """Turn on JAX's persistent compilation cache for this process; returns its directory."""
    path = cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    # Cache every program (the default skips those under 1 s): a warm run then compiles nothing, not even the
    # evaluation render (0.16 s) and the many small programs of its first calls.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    from gsjax.app.runtime.compile_log import install_from_env

    install_from_env()  # GSJAX_COMPILE_LOG: a developer's log of every compilation
    global _exported
    if _exported is None:
        from gsjax.app.runtime.programs import ExportedPrograms

        _exported = ExportedPrograms(path / "exported")  # JAX's cache reads only its own *-cache files here
    return path


def exported_call() -> Callable | None:
    """How the shell calls ``run_chunk`` (:meth:`gsjax.app.runtime.programs.ExportedPrograms.call`: the exported program
    beside the compilation cache), or None (a plain call) while the cache is not enabled."""
    return None if _exported is None else _exported.call
