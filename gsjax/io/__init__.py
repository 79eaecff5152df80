"""File formats and host-side I/O: the only place (with the shell, :mod:`gsjax.app`) that touches
the file system.

* :mod:`gsjax.io.atomic`: ``atomic_write_bytes / _text / _json`` (temp file + ``os.replace``), used by every writer.
* :mod:`gsjax.io.trajectory`: TUM trajectory files (camera-to-world).
* :mod:`gsjax.io.ply`: standard 3DGS PLY export/import of a Gaussian map.
* :mod:`gsjax.io.images`: colour/depth PNGs, colour-mapped depth, render-vs-input panels (OpenCV).
* :mod:`gsjax.io.plots`: trajectory top view and errors over time (matplotlib Agg).

The first three are re-exported here; ``images`` and ``plots`` are imported explicitly (they pull in OpenCV and
matplotlib).
"""

from gsjax.io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text
from gsjax.io.ply import read_ply, write_ply
from gsjax.io.trajectory import read_tum_trajectory, write_tum_trajectory

__all__ = [
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "read_ply",
    "read_tum_trajectory",
    "write_ply",
    "write_tum_trajectory",
]
