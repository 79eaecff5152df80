"""Exported SLAM programs (``gsjax.app.runtime.programs``): the same results as calling ``run_chunk``, a new store
reads the file instead of tracing, keys follow the static config and the source, and anything unreadable or
unexportable falls back."""

from __future__ import annotations

import dataclasses
import fcntl
import os
import subprocess
import sys
import textwrap
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax import slam
from gsjax.app.runtime import programs
from gsjax.app.runtime.programs import ExportedPrograms, program_key, source_digest
from gsjax.slam.system import run_chunk
from tests.support.tiny_slam import CHUNK, assert_trees_equal, tiny_config, tiny_sequence


def run_tiny(call=None):
    return slam.run(tiny_sequence(), tiny_config(), tiny_sequence().intrinsics, chunk=CHUNK, call=call)


@pytest.fixture(scope="module")
def direct():
    return run_tiny()


def test_an_exported_program_gives_the_direct_result_and_a_new_store_reads_it_back(tmp_path, direct, monkeypatch):
    store = ExportedPrograms(tmp_path)
    exported = run_tiny(store.call)
    assert_trees_equal(exported.outputs, direct.outputs)
    assert_trees_equal(exported.state, direct.state)
    assert len(list(tmp_path.glob("*.exported"))) == 1  # both chunks: one program
    # ... compiled once: the first chunk's fresh (uncommitted) state and the second's (the first's output,
    # committed) are called alike.
    (program,) = store._programs.values()
    assert program._cache_size() == 1

    def no_export(*args):
        raise AssertionError("exported again instead of read back")

    monkeypatch.setattr(ExportedPrograms, "_export", no_export)
    again = run_tiny(ExportedPrograms(tmp_path).call)  # as a new process: nothing in memory
    assert_trees_equal(again.outputs, direct.outputs)


def test_an_unreadable_file_is_exported_again_and_an_unexportable_program_is_called(tmp_path, direct, monkeypatch):
    run_tiny(ExportedPrograms(tmp_path).call)
    (path,) = tmp_path.glob("*.exported")
    path.write_bytes(b"not a module")
    assert_trees_equal(run_tiny(ExportedPrograms(tmp_path).call).outputs, direct.outputs)
    assert path.read_bytes() != b"not a module"

    def refuse(fn):
        raise ValueError("cannot export")

    monkeypatch.setattr(jax.export, "export", refuse)
    other = tmp_path / "other"
    assert_trees_equal(run_tiny(ExportedPrograms(other).call).outputs, direct.outputs)
    assert not list(other.glob("*.exported"))


_PROGRAM = "jax.jit(jnp.cosh)"  # the same key in both processes (a lambda's module differs)


def test_a_process_that_keeps_its_own_executables_reads_them_back_instead_of_compiling(tmp_path, monkeypatch):
    """Process 1 of a multi-process CPU sweep (JAX's cache never holds its programs) writes its compiled program
    beside the exported module, and its next run reads the file instead of compiling. Process 0 of a one-process
    job plays it here; the writer is a process of its own, as a previous run is (XLA:CPU cannot load an executable
    into the process that compiled the same program)."""
    code = textwrap.dedent(f"""
        import sys, jax, jax.numpy as jnp
        from gsjax.app.runtime import programs
        programs.keeps_own_executables = lambda: True
        print(programs.ExportedPrograms(sys.argv[1]).call({_PROGRAM}, jnp.arange(5.0)))
    """)
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert len(list(tmp_path.glob("*.process0.*.executable"))) == 1

    def no_compile(*args, **kwargs):
        raise AssertionError("compiled again instead of read back")

    monkeypatch.setattr(programs, "keeps_own_executables", lambda: True)
    monkeypatch.setattr(jax.stages.Lowered, "compile", no_compile)
    store = ExportedPrograms(tmp_path)
    result = store.call(eval(_PROGRAM), jnp.arange(5.0))
    np.testing.assert_allclose(np.asarray(result), np.cosh(np.arange(5.0), dtype=np.float32), rtol=1e-6)
    (program,) = store._programs.values()
    assert isinstance(program, jax.stages.Compiled)  # the file's executable, not the fallback


def test_the_key_follows_static_fields_shapes_and_the_source_not_traced_values():
    config = tiny_config()
    state = slam.run(tiny_sequence(), config, tiny_sequence().intrinsics, chunk=CHUNK).state
    args = (state, None, None, config, tiny_sequence().intrinsics)
    key = program_key(run_chunk, args, "digest")
    traced = dataclasses.replace(config, tracking=dataclasses.replace(config.tracking, lr_trans=1e-3))
    counted = dataclasses.replace(config, tracking=dataclasses.replace(config.tracking, iters=4))  # within its cap
    static = dataclasses.replace(config, tracking=dataclasses.replace(config.tracking, optimizer="lm"))
    for same in (traced, counted):
        assert program_key(run_chunk, (state, None, None, same, args[4]), "digest") == key
    assert program_key(run_chunk, (state, None, None, static, args[4]), "digest") != key
    assert program_key(run_chunk, args, "other digest") != key
    grown = dataclasses.replace(state, gaussians=state.gaussians.grow(2 * state.gaussians.capacity))
    assert program_key(run_chunk, (grown,) + args[1:], "digest") != key


def test_the_source_digest_changes_with_any_module(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("x = 1\n")
    (package / "sub" / "b.py").write_text("y = 2\n")
    before = programs.source_digest(package)
    (package / "sub" / "b.py").write_text("y = 3\n")
    assert programs.source_digest(package) != before


def test_a_first_call_waits_while_another_process_compiles_the_same_program(tmp_path):
    """The first call of a program in a process takes the program's lock (a flock beside its file: another process
    compiling the same program holds it), so processes that start together compile it once."""
    store = ExportedPrograms(tmp_path)
    add_one = jax.jit(lambda x: x + 1.0)
    x = jnp.zeros(3)
    lock = os.open(tmp_path / f"{program_key(add_one, (x,), source_digest())}.lock", os.O_RDWR | os.O_CREAT)
    fcntl.flock(lock, fcntl.LOCK_EX)  # as another process compiling it would
    results = []
    caller = threading.Thread(target=lambda: results.append(store.call(add_one, x)))
    caller.start()
    caller.join(1.0)
    assert caller.is_alive() and not results  # waiting for the lock
    os.close(lock)
    caller.join(60)
    np.testing.assert_array_equal(np.asarray(results[0]), np.ones(3))
    assert store.call(add_one, x) is not None  # later calls take no lock
