"""SplaTAM's rendering metrics of a finished map (method_spec B.3): which frames are evaluated, and a frame's render of
the final map at its estimated pose (canonical rendering) against its input, masked by valid depth."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics
from gsjax.eval.image import render_metrics_splatam
from gsjax.eval.run_metrics import RenderMetrics
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, render
from gsjax.raster.render import Render

# Module-level jit: every run of a process (a sweep's configs) shares one traced and compiled program.
_render = jax.jit(render)


def is_evaluation_frame(t: int, eval_every: int) -> bool:
    """SplaTAM's evaluation frames: t = 0 and (t + 1) % eval_every == 0."""
    return t == 0 or (t + 1) % eval_every == 0


def evaluation_frames(skipped: np.ndarray, eval_every: int) -> list[int]:
    """The frames a run's render metrics are measured on.

    Args:
      skipped: [T] bool, the frames the run skipped for lack of depth (never evaluated).
      eval_every: SplaTAM's rule (:func:`is_evaluation_frame`).

    Returns:
      The evaluation frames t in increasing order.
    """
    return [t for t in range(len(skipped)) if is_evaluation_frame(t, eval_every) and not skipped[t]]


def frame_render_metrics(gaussians: Gaussians, w2c: np.ndarray, intrinsics: Intrinsics, settings: RasterSettings,
                         color: np.ndarray, depth: np.ndarray) -> tuple[Render, dict[str, float]]:
    """One frame's render of the map and its metrics.

    Args:
      gaussians: the final map.
      w2c: [4, 4] the frame's estimated world-to-camera pose (m).
      intrinsics: the camera; settings: the rasterizer's.
      color: [H, W, 3] the input colour in [0, 1]; depth: [H, W] its depth (m, 0 invalid).

    Returns:
      The render (canonical: no CB-KNN), and its metrics against the input (:func:`render_metrics_splatam`: PSNR,
        SSIM, MS-SSIM, depth L1 in m, ...), as floats.
    """
    out = _render(gaussians, jnp.asarray(w2c, jnp.float32), intrinsics, settings)
    values = render_metrics_splatam(out.color, out.depth, jnp.asarray(color), jnp.asarray(depth))
    return out, {k: float(v) for k, v in values.items()}


def render_metrics(frames: list[int], per_frame: list[dict[str, float]]) -> RenderMetrics:
    """The run's render metrics from its evaluation frames' (:func:`frame_render_metrics`): each frame's, and their
    mean (depth L1 also in cm); empty (``mean`` None) without a frame."""
    if not per_frame:
        return RenderMetrics()
    mean = {k: float(np.mean([p[k] for p in per_frame])) for k in per_frame[0]}
    return RenderMetrics(frames=frames, mean=dict(mean, depth_l1_cm=100 * mean["depth_l1_m"]), per_frame=per_frame)
