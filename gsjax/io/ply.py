"""Standard 3DGS PLY export/import of a :class:`~gsjax.gaussians.Gaussians` map (plain numpy; not plyfile, which the
3DGS reference code uses: it is GPL-3.0, and a copyleft runtime dependency would bind gsjax's users).

Layout (binary little-endian, one ``vertex`` element of float32 properties, the order of the original 3DGS code,
with SH degree 0 so there are no ``f_rest_*``) that common splat viewers open:

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  opacity  scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3

Conventions: ``f_dc = (rgb - 0.5) / C0`` with ``C0 = 0.28209479177387814`` (the degree-0 SH basis), so a viewer's
``0.5 + C0 f_dc`` gives back the colour; ``opacity`` is the logit (pre-sigmoid); ``scale_k`` is the log std-dev
(isotropic: the same value three times); ``rot`` is the identity quaternion (w, x, y, z) = (1, 0, 0, 0); normals are
zero. Only active Gaussians are written.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from gsjax.gaussians import Gaussians, check_gaussians
from gsjax.io.atomic import atomic_write_bytes

SH_C0 = 0.28209479177387814
PROPERTIES = (
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
    "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
)  # fmt: skip
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
    "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip


def ply_header(num_vertices: int) -> bytes:
    """The exact ASCII header gsjax writes for ``num_vertices`` Gaussians."""
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {int(num_vertices)}"]
    lines += [f"property float {name}" for name in PROPERTIES]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def gaussians_to_ply_bytes(gaussians: Gaussians) -> bytes:
    """Encode the active Gaussians of a map as a standard 3DGS PLY file (header + float32 records)."""
    check_gaussians(gaussians)
    active = np.asarray(gaussians.active, bool)
    n = int(active.sum())
    records = np.zeros((n, len(PROPERTIES)), dtype="<f4")
    records[:, 0:3] = np.asarray(gaussians.means, np.float64)[active]
    records[:, 6:9] = (np.asarray(gaussians.rgb, np.float64)[active] - 0.5) / SH_C0
    records[:, 9] = np.asarray(gaussians.logit_opacities)[active]
    records[:, 10:13] = np.asarray(gaussians.log_scales)[active][:, None]
    records[:, 13] = 1.0
    return ply_header(n) + records.tobytes()


def write_ply(path: str | os.PathLike, gaussians: Gaussians) -> Path:
    """Write the active Gaussians as a standard 3DGS PLY file (binary little-endian float32), atomically.

    Args:
      path: the destination; its parent directory must exist.
      gaussians: the map; inactive slots are not written.

    Returns:
      ``path`` as a Path.
    """
    return atomic_write_bytes(path, gaussians_to_ply_bytes(gaussians))


def _parse_header(data: bytes, path: Path) -> tuple[int, int, np.dtype]:
    """(header length in bytes, vertex count, structured dtype of a vertex record) of a binary LE PLY file."""
    end = data.find(b"end_header")
    newline = data.find(b"\n", end)
    if not data.startswith(b"ply") or end < 0 or newline < 0:
        raise ValueError(f"{path}: not a PLY file (no 'ply' magic or no 'end_header')")
    lines = data[:end].decode("ascii", errors="replace").splitlines()[1:]
    count, fields, in_vertex, seen_element = None, [], False, False
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if words[1:2] != ["binary_little_endian"]:
                raise ValueError(f"{path}: only 'format binary_little_endian' PLY is supported, got {line!r}")
        elif words[0] == "element":
            if not seen_element and words[1:2] != ["vertex"]:
                raise ValueError(f"{path}: the first element must be 'vertex', got {line!r}")
            in_vertex, seen_element = words[1] == "vertex", True
            if in_vertex:
                count = int(words[2])
        elif words[0] == "property" and in_vertex:
            if words[1] == "list" or words[1] not in _PLY_TYPES:
                raise ValueError(f"{path}: unsupported vertex property {line!r}")
            fields.append((words[2], "<" + _PLY_TYPES[words[1]]))
    if count is None:
        raise ValueError(f"{path}: no 'element vertex' in the header")
    return newline + 1, count, np.dtype(fields)


def read_ply(path: str | os.PathLike, capacity: int | None = None) -> Gaussians:
    """Read a 3DGS PLY file (as written by :func:`write_ply`, or by other tools if isotropic) into a map.

    Colours come from ``f_dc`` (``rgb = 0.5 + C0 f_dc``; any ``f_rest_*`` is ignored), opacities and scales are
    taken as logit and log std-dev. Rotations are ignored (irrelevant for isotropic Gaussians).

    Args:
      path: the PLY file.
      capacity: number of slots of the returned map (default: the number of Gaussians in the file).

    Returns:
      Gaussians (float32) of ``capacity`` slots, the file's n Gaussians first and active, the rest free.

    Raises:
      ValueError: naming the file if it is malformed, lacks a required property, or holds anisotropic Gaussians.
    """
    path = Path(path)
    data = path.read_bytes()
    offset, n, dtype = _parse_header(data, path)
    missing = [p for p in ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0") if p not in dtype.names]
    if missing:
        raise ValueError(f"{path}: missing vertex properties {missing}")
    if len(data) < offset + n * dtype.itemsize:
        raise ValueError(f"{path}: truncated: {n} vertices need {n * dtype.itemsize} bytes after the header, "
                         f"found {len(data) - offset}")
    v = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
    log_scales = np.asarray(v["scale_0"], np.float32)
    for other in ("scale_1", "scale_2"):
        if other in dtype.names and not np.allclose(v[other], log_scales, rtol=0, atol=1e-6):
            raise ValueError(f"{path}: anisotropic Gaussians ({other} differs from scale_0); gsjax maps are isotropic")
    capacity = n if capacity is None else int(capacity)
    if capacity < n:
        raise ValueError(f"capacity {capacity} is smaller than the {n} Gaussians in {path}")
    f_dc = np.stack([v["f_dc_0"], v["f_dc_1"], v["f_dc_2"]], 1).astype(np.float64)
    columns = {
        "means": np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float32),
        "log_scales": log_scales,
        "logit_opacities": np.asarray(v["opacity"], np.float32),
        "rgb": (0.5 + SH_C0 * f_dc).astype(np.float32),
    }
    padded = {k: np.concatenate([x, np.zeros((capacity - n, *x.shape[1:]), np.float32)]) for k, x in columns.items()}
    return Gaussians(**{k: jnp.asarray(x) for k, x in padded.items()}, active=jnp.arange(capacity) < n)
