"""Atomic file writes: a reader sees the old file or the complete new one, never a partial file.

The data goes to a temporary file in the destination's directory (same file system), is flushed and fsynced,
then ``os.replace``d over the destination. If anything fails before the replace, the temporary file is removed
and the old destination is left untouched. Every writer in :mod:`gsjax.io` goes through here.
"""

from __future__ import annotations

import json
import os
import re
import secrets
from pathlib import Path
from typing import Any

_TEMPORARY = re.compile(r"\..+\.\d+\.[0-9a-f]{8}\.tmp")


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write bytes to a file atomically.

    A new file gets the usual permissions (0o666 minus the umask); an existing file keeps its mode.

    Args:
      path: the destination; its parent directory must exist.
      data: the file's whole content.

    Returns:
      ``path`` as a Path.

    Raises:
      FileNotFoundError: the parent directory does not exist.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {path.parent} does not exist")
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if path.exists():
            os.chmod(tmp, path.stat().st_mode & 0o7777)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)
    return path


def _fsync_dir(directory: Path) -> None:
    """Make the rename durable where the platform allows opening directories (best effort)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write a string to a file atomically (no newline translation).

    Args:
      path: the destination; its parent directory must exist.
      text: the file's whole content.
      encoding: the text encoding.

    Returns:
      ``path`` as a Path.
    """
    return atomic_write_bytes(path, text.encode(encoding))


def atomic_write_json(path: str | os.PathLike, obj: Any, indent: int = 2) -> Path:
    """Write an object as JSON atomically, keys in their order, with a final newline.

    Args:
      path: the destination; its parent directory must exist.
      obj: a JSON-serialisable object; NaN and inf are rejected (they are not JSON): use None instead.
      indent: spaces per indentation level.

    Returns:
      ``path`` as a Path.

    Raises:
      ValueError: ``obj`` holds NaN or inf.
      TypeError: ``obj`` holds something that is not JSON-serialisable.
    """
    return atomic_write_text(path, json.dumps(obj, indent=indent, allow_nan=False, sort_keys=False) + "\n")


def remove_stale_temporaries(directory: str | os.PathLike) -> list[Path]:
    """Remove the temporary files that writers killed mid-write left in ``directory`` (a process killed by
    SIGKILL gets no chance to); returns them. Only names of :func:`atomic_write_bytes`'s pattern are touched."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    stale = [p for p in directory.iterdir() if p.is_file() and _TEMPORARY.fullmatch(p.name)]
    for path in stale:
        path.unlink(missing_ok=True)
    return stale
