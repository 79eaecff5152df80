"""The allocator setting of long runs (gsjax.app.runtime.memory): glibc's malloc limited to a few arenas, once,
unless the user chose with MALLOC_ARENA_MAX."""

from __future__ import annotations

import platform

import pytest

from gsjax.app.runtime import memory


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_the_arenas_are_limited_once_on_glibc(monkeypatch):
    monkeypatch.delenv("MALLOC_ARENA_MAX", raising=False)
    monkeypatch.setattr(memory, "_done", False)
    assert memory.limit_malloc_arenas() is True
    assert memory.limit_malloc_arenas() is True  # idempotent


def test_a_users_malloc_arena_max_stands(monkeypatch):
    monkeypatch.setenv("MALLOC_ARENA_MAX", "4")
    monkeypatch.setattr(memory, "_done", False)
    assert memory.limit_malloc_arenas() is False
