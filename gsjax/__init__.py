"""gsjax: dense RGB-D SLAM with 3D Gaussian Splatting and adaptive kernel smoothing (CB-KNN), in pure JAX.

The names most users need, flat (the SLAM system is :mod:`gsjax.slam`)::

    import gsjax
    out = gsjax.render(gaussians, w2c, intrinsics, gsjax.RasterSettings(), cbknn=gsjax.CBKNN(alpha=0.2))
    sequence = gsjax.open_sequence("tum", "my_room", intrinsics=(525.0, 525.0, 319.5, 239.5))
"""

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.frame import Frame
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, render
from gsjax.raster.cbknn import CBKNN

# The readers' names load gsjax.data (every reader, OpenCV, the bag libraries) only when asked for, so importing the
# core (gsjax.raster, gsjax.slam) loads no reader.
_FROM_DATA = ("DatasetError", "DatasetWarning", "Sequence", "open_sequence")


def __getattr__(name: str):
    if name in _FROM_DATA:
        import gsjax.data

        return getattr(gsjax.data, name)
    raise AttributeError(f"module 'gsjax' has no attribute {name!r}")


__all__ = [
    "CBKNN",
    "DatasetError",
    "DatasetWarning",
    "Frame",
    "Gaussians",
    "Intrinsics",
    "RasterSettings",
    "Sequence",
    "make_intrinsics",
    "open_sequence",
    "render",
]
__version__ = "0.1.0"
