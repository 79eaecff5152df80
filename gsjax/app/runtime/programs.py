"""Warm runs that do not trace the SLAM program: ``run_chunk`` exported once (:mod:`jax.export`) and kept beside
JAX's compilation cache, keyed by everything it depends on.

Tracing ``run_chunk`` (Python running every stage of a SLAM step symbolically) takes seconds on every run, even when
JAX's persistent cache holds the compiled executable: the cache is keyed by the traced program, so it has to be
traced first. :class:`ExportedPrograms` keys the *traced program itself* instead: the gsjax source, the JAX version,
the platform, the arguments' tree structure (the static config fields) and shapes. On a hit it deserializes the
exported StableHLO (milliseconds) and calls it through ``jax.jit``, whose compilation is then a hit in JAX's
persistent cache; on a miss it exports (one trace, as before) and stores the module for the next process. Anything
that goes wrong (a module JAX cannot export or read back) falls back to calling the function itself.

A process other than the first of a multi-process CPU job also keeps its compiled executables beside the modules
(:func:`keeps_own_executables`): JAX's persistent cache would never hold them.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
import pickle
import socket
from collections.abc import Callable
from pathlib import Path

import jax
import jaxlib

from gsjax.io.atomic import atomic_write_bytes

log = logging.getLogger("gsjax")

_SOURCE = Path(__file__).resolve().parents[1]  # the gsjax package
_registered = False


def _register_serialization() -> None:
    """Let :mod:`jax.export` serialize the pytrees ``run_chunk`` takes and returns (their static fields pickled)."""
    global _registered
    if _registered:
        return
    from jax import export

    from gsjax.camera import Intrinsics
    from gsjax.frame import Frame
    from gsjax.gaussians import Gaussians
    from gsjax.slam.config import CONFIG_CLASSES
    from gsjax.slam.state import KeyframeBuffer, SlamState
    from gsjax.slam.system import StepOutputs

    for cls in (SlamState, KeyframeBuffer, Gaussians, Frame, Intrinsics, *CONFIG_CLASSES):
        export.register_pytree_node_serialization(cls, serialized_name=f"gsjax.{cls.__qualname__}",
                                                  serialize_auxdata=pickle.dumps, deserialize_auxdata=pickle.loads)
    export.register_namedtuple_serialization(StepOutputs, serialized_name="gsjax.StepOutputs")
    _registered = True


def source_digest(root: Path = _SOURCE) -> str:
    """sha256 of every ``.py`` file under ``root`` (relative paths and contents, in sorted order)."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


class ExportedPrograms:
    """Exported programs under ``directory``, one file per key (:func:`program_key`).

    ``call(fn, *args)`` is ``fn(*args)`` for a jitted ``fn`` of arrays and pytrees: from this process's memory, else
    from the file, else exported now (and written for the next process)."""

    def __init__(self, directory: Path):
        self.directory = Path(directory)
        self._digest: str | None = None  # of the gsjax source, on the first call
        self._programs: dict[str, Callable] = {}

    def call(self, fn: Callable, *args):
        self._digest = self._digest or source_digest()
        key = program_key(fn, args, self._digest)
        program = self._programs.get(key)
        if program is None:
            # The first call compiles (or loads from JAX's cache) and dispatches: one process at a time per program,
            # so processes that start together (a multi-process sweep, the test workers) compile it once, the others
            # load it. Dispatch is asynchronous: the lock is not held while the program runs.
            with self._compiling(key):
                program = self._load(key) or self._export(fn, args, key)
                if program is not fn and keeps_own_executables():
                    program = self._executable(key, program, args)
                self._programs[key] = program
                return self._invoke(fn, program, args)
        return self._invoke(fn, program, args)

    @staticmethod
    def _invoke(fn: Callable, program: Callable, args: tuple):
        # An exported program's arguments are committed (see committed()); a function not exported is called as
        # a direct call calls it, so that it is the direct call's program (and JAX's cache entry).
        return fn(*args) if program is fn else program(*committed(args))

    @contextlib.contextmanager
    def _compiling(self, key: str):
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.directory / f"{key}.lock", os.O_RDWR | os.O_CREAT, 0o644)
        except OSError:  # a read-only cache: compile without the lock
            yield
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # released by the kernel if this process dies
            yield
        finally:
            os.close(fd)

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.exported"

    def _load(self, key: str) -> Callable | None:
        path = self._path(key)
        if not path.exists():
            return None
        try:
            _register_serialization()
            from jax import export

            return jax.jit(export.deserialize(bytearray(path.read_bytes())).call)
        except Exception as error:  # a file from an interrupted or foreign writer: export again
            log.debug("exported program %s unreadable (%s); exporting again", path, error)
            return None

    def _executable(self, key: str, program: Callable, args: tuple) -> Callable:
        """``program`` compiled for this process's devices, read from its own file when an earlier run wrote one (see
        :func:`keeps_own_executables`), else compiled now and written; ``program`` itself when either fails."""
        from jax.experimental import serialize_executable

        args = committed(args)
        if {d for x in jax.tree.leaves(args) if isinstance(x, jax.Array) for d in x.devices()} != set(
                jax.local_devices()):
            return program  # a program over several processes' devices: JAX's cache holds it (its key is shared)
        # The host in the name too: an executable is machine code for the CPU that compiled it.
        path = self.directory / f"{key}.process{jax.process_index()}.{socket.gethostname()}.executable"
        if path.exists():
            try:
                return serialize_executable.deserialize_and_load(*pickle.loads(path.read_bytes()),
                                                                 execution_devices=jax.local_devices())
            except Exception as error:  # a file from an interrupted or foreign writer: compile again
                log.debug("executable %s unreadable (%s); compiling again", path, error)
        try:
            compiled = program.lower(*args).compile()
            atomic_write_bytes(path, pickle.dumps(serialize_executable.serialize(compiled)))
            return compiled
        except Exception as error:
            log.debug("%s: no executable of this process's own (%s); JAX compiles it", path, error)
            return program

    def _export(self, fn: Callable, args: tuple, key: str) -> Callable:
        try:
            _register_serialization()
            from jax import export

            exported = export.export(fn)(*args)
            self.directory.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(self._path(key), bytes(exported.serialize()))
            return jax.jit(exported.call)
        except Exception as error:  # not exportable (e.g. a custom call without a stability guarantee)
            log.debug("%s not exported (%s); calling it directly", getattr(fn, "__name__", fn), error)
            return fn


def keeps_own_executables() -> bool:
    """Whether this process keeps its compiled programs itself: a process other than the first of a multi-process
    job on CPUs, with one device (a program then runs on that device alone). JAX writes its persistent cache from
    process 0 only, and a CPU program's cache key holds its device assignment, so without its own files such a
    process would compile every program anew in every run (measured: process 1 of the suite's two-process sweep
    compiled its 20 s SLAM program on every warm run)."""
    return (jax.process_count() > 1 and jax.process_index() != 0 and jax.default_backend() == "cpu"
            and jax.local_device_count() == 1)


def committed(args):
    """``args`` with every leaf committed to the one device the committed leaves are on (the default device when
    none is): ``jax.jit`` of an exported module compiles anew for each pattern of committed and uncommitted
    arguments (measured: a run's first chunk, from a fresh state, and its second, from the first's output, compiled
    the same 10 s program twice). Leaves on several devices are left as they are."""
    leaves = jax.tree.leaves(args)
    devices = {d for x in leaves if isinstance(x, jax.Array) and x.committed for d in x.devices()}
    if len(devices) > 1:
        return args
    device = devices.pop() if devices else jax.devices()[0]
    return jax.tree.map(lambda x: x if isinstance(x, jax.Array) and x.committed else jax.device_put(x, device), args)


def program_key(fn: Callable, args: tuple, digest: str) -> str:
    """What an exported ``fn(*args)`` depends on, hashed: ``fn``'s name, the gsjax source ``digest``, the JAX
    version, platform, devices and flags, the arguments' tree structure (static fields included) and every leaf's
    shape, dtype and weak type."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    device = jax.devices()[0]
    parts = [getattr(fn, "__module__", ""), getattr(fn, "__qualname__", repr(fn)), digest, jax.__version__,
             jaxlib.__version__, device.platform, device.device_kind,
             str(jax.device_count()), str(jax.config.jax_enable_x64), os.environ.get("XLA_FLAGS", ""), str(tree)]
    parts += [str(jax.typeof(leaf)) for leaf in leaves]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:32]
