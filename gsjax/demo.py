"""The built-in demo: build a Gaussian map from the synthetic scene and render it from other viewpoints.

No download: the scene is the analytic room of :mod:`gsjax.data.synthetic`. Frame 0 is turned into Gaussians
(SplaTAM's one-per-pixel initialisation at the ground-truth pose), then frames 15 and 30 add Gaussians where the
map does not yet cover them (silhouette < 0.5, SplaTAM's densification rule without optimisation). The map is
rendered at frames 0, 20 and 40 and compared with the ray-cast input. Writes render-vs-input panels, the map as a
3DGS PLY and a small JSON summary.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from gsjax.camera import se3_inverse
from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
from gsjax.eval.image import psnr
from gsjax.gaussians import Gaussians, gaussians_from_rgbd
from gsjax.io.atomic import atomic_write_json
from gsjax.io.images import render_panel, save_rgb_png
from gsjax.io.ply import write_ply
from gsjax.raster import RasterSettings, render

MAP_FRAMES = (0, 15, 30)
VIEW_FRAMES = (0, 20, 40)


def _concat(parts: list[Gaussians]) -> Gaussians:
    return Gaussians(*(jnp.concatenate([getattr(p, f) for p in parts]) for f in Gaussians.__dataclass_fields__))


def run_demo(out_dir: Path) -> Iterator[str]:
    """Run the demo, writing into ``out_dir``; yields progress lines for the shell to print."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sequence = synthetic_sequence(SyntheticConfig())
    intrinsics = sequence.intrinsics
    yield f"scene: {sequence!r}"

    settings = RasterSettings()
    parts = []
    for i in MAP_FRAMES:
        frame = sequence[i]
        mask = None
        if parts:
            covered = render(_concat(parts), se3_inverse(frame.c2w), intrinsics, settings).silhouette
            mask = covered < 0.5
        parts.append(gaussians_from_rgbd(frame.color, frame.depth, intrinsics, frame.c2w, mask, opacity=0.9))
    gaussians = _concat(parts)
    yield f"map: {int(gaussians.num_active())} Gaussians from frames {MAP_FRAMES}"

    summary = {"gaussians": int(gaussians.num_active()), "views": []}
    for i in VIEW_FRAMES:
        frame = sequence[i]
        start = time.perf_counter()
        out = render(gaussians, se3_inverse(frame.c2w), intrinsics, settings)
        out.color.block_until_ready()
        seconds = time.perf_counter() - start
        value = float(psnr(jnp.clip(out.color, 0.0, 1.0), frame.color))
        panel = render_panel(np.asarray(out.color), np.asarray(frame.color), np.asarray(out.depth),
                             np.asarray(frame.depth))
        path = save_rgb_png(out_dir / f"render_{i:03d}.png", panel)
        summary["views"].append(
            dict(frame=i, psnr_db=value, seconds=seconds, truncated_pixels=int(out.stats.pixels_truncated))
        )
        yield f"frame {i:3d}: PSNR {value:5.2f} dB, render {1e3 * seconds:7.1f} ms -> {path}"
    ply = write_ply(out_dir / "map.ply", gaussians)
    atomic_write_json(out_dir / "summary.json", summary)
    yield f"outputs in {out_dir.resolve()} (render_*.png: render | input, colour over depth; {ply.name})"
