"""``gsjax bench``: rasterizer and tracking-iteration throughput per backend on the current device.

For every (backend, size) pair, on a SplaTAM-density map of an analytic room (:mod:`gsjax.data.room`): compile
time (apart), then the median of repeated runs after a warm-up of the forward render, the forward + backward
(w.r.t. every Gaussian field and the pose, as mapping differentiates), and one tracking iteration (the SLAM
tracking loss and its gradient w.r.t. the pose tangent), the cost per pixel x candidate, and the peak memory of
a tracking iteration (XLA's buffer assignment: arguments + outputs + temporaries), and the device's own peak so
far where it reports one (a GPU; cumulative over the rows).
"""

from __future__ import annotations

import dataclasses
import math
import platform
import statistics
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import se3_exp
from gsjax.data.room import dense_surface_map, room_intrinsics
from gsjax.gaussians import Gaussians
from gsjax.raster import pallas, render
from gsjax.raster.binning import TileGrid, bin_gaussians
from gsjax.raster.project import project
from gsjax.slam.config import SlamConfig
from gsjax.slam.tracking import TrackingProblem, tracking_objective

COLUMNS = ("backend", "size", "gaussians", "mean_list", "k", "compile_s", "fwd_ms", "fwd_bwd_ms", "track_iter_ms",
           "ns_per_px_cand", "track_peak_mib", "device_peak_mib", "truncated_px")


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (width, height); ValueError naming the text otherwise."""
    try:
        width, height = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--sizes: {text!r} is not WIDTHxHEIGHT (e.g. 640x480)") from None
    if width < 8 or height < 8:
        raise ValueError(f"--sizes: {text!r} is smaller than 8x8 px")
    return width, height


def bench_map(width: int, height: int, gaussians: int | None = None, seed: int = 0):
    """(Gaussians, w2c, intrinsics) for a ``width`` x ``height`` render: the room mapped at SplaTAM's density
    (about one Gaussian per pixel), or with ``gaussians`` active Gaussians: the room mapped at the resolution
    that gives at least that many, the surplus dropped at random (the same view and field of view)."""
    if gaussians is None:
        return dense_surface_map(height, width, "mapped", seed)
    scale = math.sqrt(gaussians / (width * height))
    while True:
        map_width, map_height = max(8, round(width * scale)), max(8, round(height * scale))
        built, w2c, _ = dense_surface_map(map_height, map_width, "mapped", seed)
        active = np.flatnonzero(np.asarray(built.active))
        if active.size >= gaussians:
            break
        scale *= 1.1 * math.sqrt(gaussians / active.size)
    keep = np.random.default_rng(seed).choice(active, gaussians, replace=False)
    chosen = lambda x: jnp.asarray(np.asarray(x)[np.sort(keep)])  # noqa: E731
    g = Gaussians(chosen(built.means), chosen(built.log_scales), chosen(built.logit_opacities), chosen(built.rgb),
                  jnp.ones(gaussians, bool))
    return g, w2c, room_intrinsics(height, width)


def weighted_outputs(out, weights: jax.Array) -> jax.Array:
    """A scalar that every render output reaches: ``weights`` [H, W, 6] (colour 3, depth, silhouette, depth^2)
    times ``out``'s colour, depth, silhouette and depth^2, summed (the benchmarks' fwd+bwd loss)."""
    return (jnp.sum(weights[..., :3] * out.color) + jnp.sum(weights[..., 3] * out.depth)
            + jnp.sum(weights[..., 4] * out.silhouette) + jnp.sum(weights[..., 5] * out.depth_sq))


def median_seconds(fn: Callable, *args, repeats: int) -> float:
    """Median wall time (s) of ``fn(*args)`` over ``repeats`` runs after one warm-up run, results awaited."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _timed(fn: Callable, *args, repeats: int) -> tuple[float, float, object]:
    """(compile s, median run s after one warm-up, the lowered-and-compiled function) of ``jax.jit(fn)``."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    return compile_s, median_seconds(compiled, *args, repeats=repeats), compiled


def peak_mib(compiled) -> float | None:
    """Peak memory (MiB) of a compiled program by XLA's own account (arguments + outputs + temporaries - aliased),
    or None where the backend gives none."""
    try:
        m = compiled.memory_analysis()
        total = m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes - m.alias_size_in_bytes
        return total / 2**20
    except Exception:  # not every backend reports it
        return None


def _device_peak_mib() -> float | None:
    stats = jax.devices()[0].memory_stats() or {}
    peak = stats.get("peak_bytes_in_use")
    return None if peak is None else peak / 2**20


def measure(backend: str, width: int, height: int, gaussians: int | None, repeats: int, k: int) -> dict:
    """One row of the benchmark (see the module docstring)."""
    config = SlamConfig()
    settings = dataclasses.replace(config.raster, backend=backend, max_contributors=k)
    config = dataclasses.replace(config, raster=settings)
    g, w2c, intrinsics = bench_map(width, height, gaussians)
    weights = jax.random.normal(jax.random.PRNGKey(0), (height, width, 6))

    def forward(g, w2c):
        out = render(g, w2c, intrinsics, settings)
        return out.color, out.depth, out.silhouette, out.depth_sq, out.stats.pixels_truncated

    def weighted(fields, delta):
        out = render(Gaussians(*fields, g.active), se3_exp(delta) @ w2c, intrinsics, settings)
        return weighted_outputs(out, weights)

    fields = (g.means, g.log_scales, g.logit_opacities, g.rgb)
    delta = jnp.zeros(6, jnp.float32)
    compile_fwd, t_fwd, compiled_fwd = _timed(forward, g, w2c, repeats=repeats)
    compile_bwd, t_bwd, _ = _timed(jax.value_and_grad(weighted, argnums=(0, 1)), fields, delta, repeats=repeats)

    # One tracking iteration: the observed frame is the render at w2c; tracking starts 1 cm / 0.5 deg away.
    color, depth, _, _, truncated = compiled_fwd(g, w2c)
    start = se3_exp(jnp.asarray([0.01, 0.0, 0.0, 0.0, 0.0087, 0.0], jnp.float32)) @ w2c

    def track_iteration(delta):
        objective = tracking_objective(TrackingProblem(g, color, depth, start, intrinsics, False, 0.0), config)
        return jax.value_and_grad(objective.loss)(delta)

    compile_track, t_track, compiled_track = _timed(track_iteration, delta, repeats=repeats)

    grid = TileGrid.for_image(height, width, settings.tile_size)
    projected = project(g, w2c, intrinsics, settings.near)
    tiles = bin_gaussians(projected.uv, projected.extent, projected.depth, projected.visible, grid,
                          settings.tile_capacity, settings.intersection_capacity(g.capacity, grid))
    mean_list = float(np.minimum(np.asarray(tiles.count), settings.tile_capacity).mean())
    return dict(
        backend=backend + (" (interpret)" if settings.uses_pallas and not pallas.on_gpu() else ""),
        size=f"{width}x{height}",
        gaussians=int(np.sum(np.asarray(g.active))),
        mean_list=mean_list,
        k=k,
        compile_s=compile_fwd + compile_bwd + compile_track,
        fwd_ms=1e3 * t_fwd,
        fwd_bwd_ms=1e3 * t_bwd,
        track_iter_ms=1e3 * t_track,
        ns_per_px_cand=1e9 * t_bwd / (width * height * mean_list),
        track_peak_mib=peak_mib(compiled_track),
        device_peak_mib=_device_peak_mib(),
        truncated_px=int(truncated),
    )


def device_description() -> dict:
    device = jax.devices()[0]
    return dict(platform=jax.default_backend(), device=getattr(device, "device_kind", str(device)),
                jax=jax.__version__, host=platform.node(), python=platform.python_version())


def run_bench(backends: Sequence[str], sizes: Sequence[tuple[int, int]], gaussians: int | None, repeats: int,
              k: int, log: Callable[[str], None] = print) -> dict:
    """Measure every (backend, size) pair; logs the table as it goes and returns the JSON-ready result."""
    log(f"device: {device_description()}")
    log(format_header())
    rows = []
    for backend in backends:
        for width, height in sizes:
            rows.append(measure(backend, width, height, gaussians, repeats, k))
            log(format_row(rows[-1]))
    return dict(device=device_description(), repeats=repeats, k=k, gaussians=gaussians, rows=rows,
                note="median after one warm-up; compile time apart; peak = XLA buffer assignment of one tracking "
                     "iteration (arguments + outputs + temporaries)")


def _cell(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.1f}" if abs(value) >= 10 else f"{value:.3g}"
    return str(value)


def format_header() -> str:
    return " | ".join(f"{c:>{_width(c)}s}" for c in COLUMNS)


def format_row(row: dict) -> str:
    return " | ".join(f"{_cell(row[c]):>{_width(c)}s}" for c in COLUMNS)


def _width(column: str) -> int:
    return 18 if column == "backend" else max(9, len(column))
