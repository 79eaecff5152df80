"""``GSJAX_COMPILE_LOG=DIR``: every process that enables the compilation cache (the CLI, the tests) appends one
tab-separated line per compiled program to ``DIR/<pid>.tsv``: what it was doing (a test's id, or the command
line), the program's name, its trace, lowering and XLA compile seconds, and whether XLA's part was a hit in the
persistent cache. ``experiments/compile_log.py`` tabulates a folder of them (distinct programs by kind).

A developer's instrument: without the variable nothing is registered.
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

import jax

TRACE = "/jax/core/compile/jaxpr_trace_duration"
LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
COMPILE = "/jax/core/compile/backend_compile_duration"
CACHE_HIT = "/jax/compilation_cache/cache_hits"
COLUMNS = ("doing", "program", "trace_s", "lower_s", "compile_s", "cache_hit")


class CompileLog:
    """One process's log file; :attr:`doing` labels the lines written from then on.

    Attributes:
      path: the file appended to.
      doing: what the process is doing (a test id, or its command line).
    """

    def __init__(self, path: Path, doing: str):
        self.path = path
        self.doing = doing
        self._local = threading.local()
        self._lock = threading.Lock()

    def _pending(self) -> dict:
        if getattr(self._local, "pending", None) is None:
            self._local.pending = {"trace": 0.0, "lower": 0.0, "hit": False}
        return self._local.pending

    def on_duration(self, event: str, seconds: float, **kwargs) -> None:
        """A :mod:`jax.monitoring` duration listener: trace and lowering times add up until the compile that ends
        a program, which writes its line."""
        pending = self._pending()
        if event == TRACE:
            pending["trace"] += seconds
        elif event == LOWER:
            pending["lower"] += seconds
        elif event == COMPILE:
            line = "\t".join([self.doing, str(kwargs.get("fun_name", "?")), f"{pending['trace']:.3f}",
                              f"{pending['lower']:.3f}", f"{seconds:.3f}", str(int(pending["hit"]))])
            self._local.pending = None
            with self._lock, open(self.path, "a") as out:
                out.write(line + "\n")

    def on_event(self, event: str, **kwargs) -> None:
        """A :mod:`jax.monitoring` event listener: marks the pending compile as a persistent-cache hit."""
        if event == CACHE_HIT:
            self._pending()["hit"] = True


_log: CompileLog | None = None


def install_from_env() -> CompileLog | None:
    """Start this process's log when ``GSJAX_COMPILE_LOG`` names a folder (once per process).

    Returns:
      The log, or None when the variable is not set.
    """
    global _log
    directory = os.environ.get("GSJAX_COMPILE_LOG")
    if not directory or _log is not None:
        return _log
    Path(directory).mkdir(parents=True, exist_ok=True)
    _log = CompileLog(Path(directory) / f"{os.getpid()}.tsv", " ".join(["gsjax", *sys.argv[1:4]]))
    jax.monitoring.register_event_duration_secs_listener(_log.on_duration)
    jax.monitoring.register_event_listener(_log.on_event)
    return _log
