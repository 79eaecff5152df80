"""Tile-based differentiable Gaussian rasterizer, ``render(gaussians, w2c, intrinsics, settings)``: the XLA path
(the reference) and Pallas kernels for GPUs (``RasterSettings.backend``)."""

from gsjax.raster.render import RasterSettings, Render, RenderStats, render

__all__ = ["RasterSettings", "Render", "RenderStats", "render"]
