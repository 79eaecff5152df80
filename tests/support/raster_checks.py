"""What the rasterizer tests check with: error metrics and tolerances against the float64 reference, the
finite-difference steps and tolerance of the gradient checks, and one compiled render per settings."""

from __future__ import annotations

import jax
import numpy as np

from gsjax.raster import render

OUTPUTS = ("color", "depth", "silhouette", "depth_sq")
MAX_ABS_TOL = 5e-3
MEAN_ABS_TOL = 2e-4

_render = jax.jit(render)  # one program per static settings and shapes (jitted_render)

# Finite-difference gradient checks (shared by the canonical and the CB-KNN gradient tests).
FIELDS = ("means", "log_scales", "logit_opacities", "rgb")
STEP = {"means": 1e-6, "log_scales": 1e-6, "logit_opacities": 1e-6, "rgb": 1e-4, "pose": 1e-6}  # float64 FD steps
REL_TOL = 2e-2
GRAD_SEED = 1  # scenes.GRADIENT_SCENES at this seed have no float32-ambiguous pixel (checked in test_scenes.py)


def loss_weights(height: int, width: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return dict(
        color=rng.normal(size=(height, width, 3)),
        depth=rng.normal(size=(height, width)),
        silhouette=rng.normal(size=(height, width)),
        depth_sq=rng.normal(size=(height, width)),
    )


def jitted_render(render_settings):
    """``(g, w2c, intr) -> render(g, w2c, intr, render_settings)`` through one jitted ``render``: settings that
    differ only in traced fields (``near``) share a program, static ones (shapes) compile their own."""
    return lambda g, w2c, intr: _render(g, w2c, intr, render_settings)


def errors(out, ref, valid: np.ndarray | None = None) -> dict[str, tuple[float, float]]:
    """(max abs, mean abs) error of each output over the pixels where ``valid`` (default all)."""
    result = {}
    for name in OUTPUTS:
        got = np.asarray(getattr(out, name), np.float64)
        want = getattr(ref, name)
        assert got.shape == want.shape, f"{name}: shape {got.shape}, expected {want.shape}"
        diff = np.abs(got - want)
        if valid is not None:
            diff = diff[valid]
        result[name] = (float(diff.max()), float(diff.mean()))
    return result


def format_errors(label: str, errs: dict[str, tuple[float, float]]) -> str:
    cells = "  ".join(f"{k} max {v[0]:.2e} mean {v[1]:.2e}" for k, v in errs.items())
    return f"{label}: {cells}"


def assert_within_tolerance(label: str, errs: dict[str, tuple[float, float]]) -> None:
    for name, (max_err, mean_err) in errs.items():
        assert max_err <= MAX_ABS_TOL, f"{label}: {name} max abs error {max_err:.3e} > {MAX_ABS_TOL}"
        assert mean_err <= MEAN_ABS_TOL, f"{label}: {name} mean abs error {mean_err:.3e} > {MEAN_ABS_TOL}"


def stats_dict(out) -> dict[str, object]:
    s = out.stats
    return dict(
        tiles_overflowed=int(s.tiles_overflowed),
        pixels_out_of_k=int(s.pixels_out_of_k),
        max_residual_transmittance=float(s.max_residual_transmittance),
        truncated=bool(s.truncated),
    )
