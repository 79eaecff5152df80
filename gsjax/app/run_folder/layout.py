"""The output directory of a run: what gsjax writes there, and when a directory may be (re)used.

A run never loses what a user already has: a directory holding a previous run is used only to continue it
(``--resume``) or to replace it (``--overwrite``, which removes gsjax's own outputs only), and a non-empty directory
holding anything else is never used. One process at a time writes a directory: a live run holds its lock
(:func:`locked_run_dir`), and a second one is refused. The checks write nothing, so a refused run leaves every byte
as it was.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from gsjax.io.run_folder import RUN_FILES, SWEEP_FILES


class RunDirError(ValueError):
    """The output directory cannot be used as asked; the message says why and what to do."""




# The lock a live run holds on its directory (an advisory flock: the kernel drops it when the process ends, however
# it ends, so a killed run leaves a file that blocks nobody).
LOCK = ".gsjax.lock"


def holder(out: Path) -> int | None:
    """The pid of a live process holding ``out``'s lock, or None (no lock file, or a stale one). Writes nothing."""
    path = Path(out) / LOCK
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _pid_written(fd)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


@contextlib.contextmanager
def locked_run_dir(out: Path) -> Iterator[Path]:
    """Hold ``out``'s lock (creating ``out``) for the duration: one process at a time writes a run directory.

    Raises RunDirError, having changed nothing but creating ``out`` when missing, when a live process holds it."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunDirError(_in_use(out, _pid_written(fd))) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield out
    finally:
        os.close(fd)  # releases the lock


def _pid_written(fd: int) -> int:
    """The pid the lock's holder wrote into the file open as ``fd`` (-1 when it has not yet, or it is unreadable)."""
    text = os.read(fd, 64).decode("ascii", "replace").strip()
    return int(text) if text.isdigit() else -1


def _in_use(out: Path, pid: int) -> str:
    who = f"process {pid}" if pid > 0 else "another process"
    return (f"--out {out} is in use by a running gsjax ({who}); nothing was changed: wait for it to finish, or "
            "choose another --out")


def previous_outputs(out: Path, outputs: tuple[str, ...] = RUN_FILES) -> list[str]:
    """The names of gsjax ``outputs`` present in ``out`` (empty when it is missing or holds none)."""
    return [name for name in outputs if (Path(out) / name).exists()] if Path(out).is_dir() else []


def check_run_dir(out: Path, *, resume: bool = False, overwrite: bool = False,
                  outputs: tuple[str, ...] = RUN_FILES) -> None:
    """Raise RunDirError (naming ``--out``) unless a run may write to ``out``; writes nothing.

    Usable: a missing directory whose nearest existing parent is a writable directory; an empty writable
    directory; a directory holding a previous run (any of ``outputs``) when ``resume`` or ``overwrite`` is given;
    never a directory a live process holds (:func:`locked_run_dir`).
    """
    out = Path(out)
    if resume and overwrite:
        raise RunDirError("--resume and --overwrite exclude each other: continue the run in --out, or replace it")
    if out.exists() and not out.is_dir():
        raise RunDirError(f"--out {out} is an existing file, not a directory; choose a directory")
    if not out.exists():
        parent = out.parent
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir():
            raise RunDirError(f"--out {out} cannot be created: {parent} is a file, not a directory")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise RunDirError(f"--out {out} cannot be created: {parent} is not writable")
        return
    pid = holder(out)
    if pid is not None:
        raise RunDirError(_in_use(out, pid))
    if not os.access(out, os.W_OK | os.X_OK):
        raise RunDirError(f"--out {out} is not writable")
    present = previous_outputs(out, outputs)
    if present:
        if not (resume or overwrite):
            listed = ", ".join(name + ("/" if (out / name).is_dir() else "") for name in present)
            again = "--resume to continue it, " if outputs in (RUN_FILES, SWEEP_FILES) else ""
            raise RunDirError(f"--out {out} holds a previous run ({listed}); nothing was changed: pass {again}"
                              "--overwrite to replace it, or choose another --out")
        return
    if any(p.name != LOCK for p in out.iterdir()):
        raise RunDirError(f"--out {out} is not empty and holds no gsjax run; choose a new or empty directory")


def clear_previous_run(out: Path, outputs: tuple[str, ...] = RUN_FILES) -> list[str]:
    """Remove gsjax's own ``outputs`` from ``out`` (``--overwrite``); other files stay. Returns the names removed."""
    removed = previous_outputs(out, outputs)
    for name in removed:
        path = Path(out) / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    return removed
