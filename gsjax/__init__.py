"""gsjax: dense RGB-D SLAM with 3D Gaussian Splatting and adaptive kernel smoothing (CB-KNN), in pure JAX."""

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.gaussians import Gaussians

__all__ = ["Gaussians", "Intrinsics", "make_intrinsics"]
__version__ = "0.1.0"
