"""Tile-based differentiable Gaussian rasterizer, ``render(gaussians, w2c, intrinsics, settings)``: the XLA path
(the reference) and Pallas kernels for GPUs (``RasterSettings.backend``). ``select_slots`` chooses each pixel's
contributors at one pose so that ``render(..., selection=...)`` can composite them at nearby poses."""

from gsjax.raster.render import RasterSettings, Render, RenderStats, SlotSelection, render, select_slots

__all__ = ["RasterSettings", "Render", "RenderStats", "SlotSelection", "render", "select_slots"]
