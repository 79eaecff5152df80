"""Tile-based differentiable Gaussian rasterizer (XLA path): ``render(gaussians, w2c, intrinsics, settings)``."""

from gsjax.raster.render import RasterSettings, Render, RenderStats, render

__all__ = ["RasterSettings", "Render", "RenderStats", "render"]
