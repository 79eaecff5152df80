"""TUM-format trajectory files: one pose per line, ``timestamp tx ty tz qx qy qz qw``, camera-to-world, metres.

Lines that are empty or start with ``#`` are ignored. Quaternions are normalised on reading (files carry a few
digits only). A pose written as ``nan``/``inf`` values is read as an all-NaN matrix (an invalid pose, e.g. a
ScanNet frame without ground truth), which the metrics skip and count. Quaternion maths here is numpy float64.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from gsjax.camera import quaternion_to_rotation_np, rotation_to_quaternion_np
from gsjax.io.atomic import atomic_write_text

if TYPE_CHECKING:
    import numpy.typing as npt

HEADER = "# timestamp tx ty tz qx qy qz qw (camera-to-world, metres)\n"


def read_tum_trajectory(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory file.

    Args:
      path: the file (``timestamp tx ty tz qx qy qz qw`` lines, camera-to-world, m).

    Returns:
      (timestamps [N] float64 seconds, c2w [N, 4, 4] float64 metres).

    Raises:
      FileNotFoundError: if the file is missing.
      ValueError: naming the file and line for a malformed line, a zero quaternion or a timestamp that does not
        increase.
    """
    path = Path(path)
    stamps: list[float] = []
    poses: list[np.ndarray] = []
    with open(path, encoding="utf-8") as f:
        for lineno, line in enumerate(f, start=1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            fields = text.replace(",", " ").split()
            where = f"{path}:{lineno}"
            if len(fields) != 8:
                raise ValueError(
                    f"{where}: expected 8 numbers 'timestamp tx ty tz qx qy qz qw', got {len(fields)}: {text!r}"
                )
            try:
                values = [float(v) for v in fields]
            except ValueError:
                raise ValueError(f"{where}: not a number in {text!r}") from None
            t, xyz, q_xyzw = values[0], np.array(values[1:4]), np.array(values[4:8])
            if not np.isfinite(t):
                raise ValueError(f"{where}: timestamp must be finite, got {fields[0]!r}")
            if stamps and not t > stamps[-1]:
                raise ValueError(f"{where}: timestamp {fields[0]} does not increase (previous {stamps[-1]!r})")
            c2w = np.full((4, 4), np.nan)
            if np.isfinite(xyz).all() and np.isfinite(q_xyzw).all():
                norm = np.linalg.norm(q_xyzw)
                if not norm > 1e-6:
                    raise ValueError(f"{where}: quaternion (qx qy qz qw) has zero length: {text!r}")
                c2w = np.eye(4)
                c2w[:3, :3] = quaternion_to_rotation_np(np.roll(q_xyzw / norm, 1))
                c2w[:3, 3] = xyz
            stamps.append(t)
            poses.append(c2w)
    return np.asarray(stamps, np.float64).reshape(-1), np.asarray(poses, np.float64).reshape(-1, 4, 4)


def format_tum_trajectory(timestamps: npt.ArrayLike, c2w: npt.ArrayLike) -> str:
    """The text of a TUM trajectory file (with a comment header). Numbers are written with the shortest repr that
    reads back to the same float64, so a write/read round trip is exact up to the quaternion conversion."""
    timestamps = np.asarray(timestamps, np.float64)
    c2w = np.asarray(c2w, np.float64)
    if c2w.ndim != 3 or c2w.shape[1:] != (4, 4) or timestamps.shape != (len(c2w),):
        raise ValueError(f"need timestamps [N] and c2w [N, 4, 4], got {list(timestamps.shape)} and {list(c2w.shape)}")
    if not np.isfinite(timestamps).all() or np.any(np.diff(timestamps) <= 0):
        raise ValueError("timestamps must be finite and strictly increasing")
    q_wxyz = rotation_to_quaternion_np(np.nan_to_num(c2w[:, :3, :3]))
    lines = [HEADER]
    for t, pose, q in zip(timestamps, c2w, q_wxyz):
        if np.isfinite(pose).all():
            values = [*pose[:3, 3], q[1], q[2], q[3], q[0]]
        else:
            values = [np.nan] * 7
        lines.append(" ".join(repr(float(v)) for v in (t, *values)) + "\n")
    return "".join(lines)


def write_tum_trajectory(path: str | os.PathLike, timestamps: npt.ArrayLike, c2w: npt.ArrayLike) -> Path:
    """Write poses as a TUM trajectory file (``timestamp tx ty tz qx qy qz qw``), atomically.

    Args:
      path: the destination; its parent directory must exist.
      timestamps: [N] timestamps (s), finite and strictly increasing.
      c2w: [N, 4, 4] camera-to-world poses (m); a non-finite pose is written as ``nan`` (read back as invalid).

    Returns:
      ``path`` as a Path.

    Raises:
      ValueError: the shapes do not match, or the timestamps are not finite and strictly increasing.
    """
    return atomic_write_text(path, format_tum_trajectory(timestamps, c2w))
