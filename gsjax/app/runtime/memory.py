"""The process's allocator, set once for long runs.

glibc's malloc gives each thread that allocates its own arena (up to 8 per core) and keeps freed memory in it.
Orbax's checkpoint writes allocate from tensorstore's thread pool, so a run that checkpoints every few frames held
~1.3 GiB resident where the same run without checkpoints held ~0.68 GiB (300 synthetic frames at 40x30,
``experiments/long_run.py``); with the arenas limited to two it holds ~0.63 GiB either way.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

M_ARENA_MAX = -8  # glibc's mallopt parameter number
ARENAS = 2

_done = False


def limit_malloc_arenas(arenas: int = ARENAS) -> bool:
    """Limit glibc's malloc to ``arenas`` arenas for the rest of the process (threads started later share them);
    whether it took effect (False off glibc, e.g. macOS, or when ``MALLOC_ARENA_MAX`` is set: the user's choice
    stands). Idempotent."""
    global _done
    if _done or os.environ.get("MALLOC_ARENA_MAX"):
        return _done
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        _done = bool(libc is not None and hasattr(libc, "mallopt") and libc.mallopt(M_ARENA_MAX, arenas) == 1)
    except OSError:
        _done = False
    return _done
