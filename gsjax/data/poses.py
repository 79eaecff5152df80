"""Ground-truth pose parsing and checks, host-side in float64 (jax runs float32 here, too coarse for GT).

Poses are camera-to-world 4x4 matrices (m). Ground truth serves evaluation only, so a bad pose never stops a run:
a pose whose numbers are not all finite (ScanNet writes ``-inf`` where its reconstruction lost track) or that is
not a rigid transform is flagged invalid, with a :class:`DatasetWarning` naming the file, and its frame is left out
of the evaluation. A frame without a pose (no file, no line) is simply flagged invalid. A pose file that cannot be
parsed at all is an error.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from gsjax.camera import rigidity_error
from gsjax.data.errors import DatasetError, DatasetWarning

# Largest tolerated |R^T R - I|, |det R - 1| or deviation of the last row from (0, 0, 0, 1). Real GT is far
# inside (7-Scenes' KinectFusion poses: 1.5e-4; ScanNet and Replica: ~1e-7); scaled or sheared matrices are far out.
RIGIDITY_TOLERANCE = 1e-2


def warn_bad_poses(where: list[str], bad: np.ndarray, problem: str) -> None:
    """One DatasetWarning for the poses flagged in ``bad`` [T] bool: the first one's source and the count."""
    count = int(np.sum(bad))
    if count:
        first = where[int(np.flatnonzero(bad)[0])]
        warnings.warn(f"{first}: {problem}; left out of the evaluation ({count} such pose(s) in all)", DatasetWarning,
                      stacklevel=3)


def check_poses(c2w: np.ndarray, where: list[str], present: np.ndarray | None = None) -> np.ndarray:
    """Poses [T, 4, 4] -> valid [T] bool: present, finite and rigid; ``where[i]`` names pose i's source.

    ``present`` [T] bool marks the frames that have a pose at all (default: all); the others are invalid without a
    word. Non-finite and non-rigid poses are invalid with a warning each kind (:func:`warn_bad_poses`).
    """
    present = np.ones(len(c2w), bool) if present is None else np.asarray(present, bool)
    finite = np.all(np.isfinite(c2w), axis=(-1, -2))
    # gsjax.camera's check in float32 (ample against the tolerance); non-finite poses are checked as the identity.
    error = np.asarray(rigidity_error(jnp.asarray(np.where(finite[:, None, None], c2w, np.eye(4)), jnp.float32)))
    rigid = error <= RIGIDITY_TOLERANCE  # NaN (entries beyond float32) is not rigid
    warn_bad_poses(where, present & ~finite, "pose has non-finite values")
    bad_rigid = present & finite & ~rigid
    if bad_rigid.any():
        i = int(np.flatnonzero(bad_rigid)[0])
        warn_bad_poses(where, bad_rigid, f"pose is not a rigid transform (deviation {error[i]:.3g} > "
                       f"{RIGIDITY_TOLERANCE})")
    return present & finite & rigid


def parse_numbers(line: str, count: int, where: str) -> np.ndarray:
    """Exactly ``count`` whitespace-separated floats from a text line (``inf``/``nan`` allowed) -> float64 [count]."""
    fields = line.split()
    if len(fields) != count:
        raise DatasetError(f"{where}: expected {count} numbers, got {len(fields)}: {line.strip()[:80]!r}")
    try:
        return np.array([float(f) for f in fields], np.float64)
    except ValueError:
        raise DatasetError(f"{where}: cannot parse numbers in {line.strip()[:80]!r}") from None


def data_lines(path: Path) -> list[tuple[int, str]]:
    """(1-based line number, line) for the non-empty, non-comment (``#``) lines of a text file."""
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise DatasetError(f"{path}: file is missing") from None
    except (OSError, UnicodeDecodeError) as err:
        raise DatasetError(f"{path}: cannot be read ({err})") from None
    numbered = enumerate(text.splitlines(), 1)
    return [(n, line) for n, line in numbered if line.strip() and not line.lstrip().startswith("#")]


def read_matrix(path: Path, rows: int) -> np.ndarray:
    """A text file holding a ``rows`` x ``rows`` matrix, one row per line -> float64 [rows, rows]."""
    lines = data_lines(path)
    if len(lines) != rows:
        raise DatasetError(f"{path}: expected a {rows}x{rows} matrix ({rows} lines), got {len(lines)} lines")
    return np.stack([parse_numbers(line, rows, f"{path}:{n}") for n, line in lines])


def read_pose_files(paths: list[Path]) -> tuple[np.ndarray, np.ndarray]:
    """One 4x4 camera-to-world text file per frame -> (c2w [N, 4, 4] float64, valid [N] bool).

    A missing file flags the frame invalid; a non-finite or non-rigid matrix too, with a warning
    (:func:`check_poses`); an unparsable one is an error.
    """
    c2w = np.full((len(paths), 4, 4), np.nan)
    present = np.array([path.is_file() for path in paths], bool)
    for i in np.flatnonzero(present):
        c2w[i] = read_matrix(paths[i], 4)
    return c2w, check_poses(c2w, [str(p) for p in paths], present)


def read_pose_lines(path: Path, count: int) -> tuple[np.ndarray, np.ndarray]:
    """A text file with one row-major 4x4 camera-to-world matrix (16 numbers) per line; line k is frame k ->
    (c2w [count, 4, 4] float64, valid [count] bool). Frames beyond the last line are flagged invalid."""
    lines = data_lines(path)
    c2w = np.full((count, 4, 4), np.nan)
    where = [f"{path} (frame {k}: no line)" for k in range(count)]
    for k, (n, line) in enumerate(lines[:count]):
        c2w[k] = parse_numbers(line, 16, f"{path}:{n}").reshape(4, 4)
        where[k] = f"{path}:{n}"
    return c2w, check_poses(c2w, where, np.arange(count) < len(lines))
