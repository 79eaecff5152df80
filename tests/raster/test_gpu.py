"""On a GPU: the compiled Pallas path against the XLA path on a full-size (640x480, SplaTAM-density) map, values,
statistics and gradients, canonical and CB-KNN. Skipped without a GPU (the CPU suite checks the same kernels in
interpret mode, tests/test_raster_pallas.py). ``experiments/gpu_check.sh`` runs these; with ``GSJAX_GPU_REPORT``
set, the measured differences are appended to that file as JSON lines.
"""

from __future__ import annotations

import dataclasses
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.app.bench import bench_map, weighted_outputs
from gsjax.camera import se3_exp
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, render
from gsjax.raster.cbknn import CBKNN
from gsjax.slam.config import SlamConfig

pytestmark = pytest.mark.skipif(jax.default_backend() != "gpu", reason="needs a GPU (the compiled Pallas path)")

VALUE_TOL = 1e-5  # the CPU tests' bounds; a GPU's exp and fused multiply-adds may differ in the last bits
GRAD_TOL = 1e-4
OUTPUTS = ("color", "depth", "silhouette", "depth_sq")


def _report(record: dict) -> None:
    path = os.environ.get("GSJAX_GPU_REPORT")
    if path:
        with open(path, "a") as f:
            f.write(json.dumps(record) + "\n")


@pytest.fixture(scope="module")
def scene():
    return bench_map(640, 480)


def _settings(backend: str) -> RasterSettings:
    return dataclasses.replace(SlamConfig().raster, backend=backend)


@pytest.mark.parametrize("cbknn", [None, CBKNN(alpha=0.2, k0=8.0, beta=0.3)], ids=["canonical", "cbknn"])
def test_pallas_equals_xla_on_a_640x480_map(scene, cbknn):
    g, w2c, intrinsics = scene
    out = {b: jax.jit(lambda g, w, b=b: render(g, w, intrinsics, _settings(b), cbknn=cbknn, motion=0.5))(g, w2c)
           for b in ("xla", "pallas")}
    errors = {}
    for field in OUTPUTS:
        x, y = np.asarray(getattr(out["xla"], field)), np.asarray(getattr(out["pallas"], field))
        errors[field] = float(np.abs(x - y).max() / max(1.0, np.abs(x).max()))
    same_stats = all(np.array_equal(np.asarray(a), np.asarray(b)) or np.allclose(a, b, rtol=1e-5, atol=1e-6)
                     for a, b in zip(jax.tree_util.tree_leaves(out["xla"].stats),
                                     jax.tree_util.tree_leaves(out["pallas"].stats)))
    _report(dict(test="values", cbknn=cbknn is not None, errors=errors, same_stats=bool(same_stats),
                 truncated_px=int(out["xla"].stats.pixels_truncated)))
    assert same_stats
    for field, err in errors.items():
        assert err <= VALUE_TOL, f"{field}: {err:.2e}"


@pytest.mark.parametrize("cbknn", [None, CBKNN(alpha=0.2, k0=8.0, beta=0.3)], ids=["canonical", "cbknn"])
def test_pallas_gradients_equal_xla_on_a_640x480_map(scene, cbknn):
    g, w2c, intrinsics = scene
    weights = jax.random.normal(jax.random.PRNGKey(1), (intrinsics.height, intrinsics.width, 6))

    def loss(fields, delta, backend):
        out = render(Gaussians(*fields, g.active), se3_exp(delta) @ w2c, intrinsics, _settings(backend),
                     cbknn=cbknn, motion=0.5)
        return weighted_outputs(out, weights)

    fields = (g.means, g.log_scales, g.logit_opacities, g.rgb)
    grads = {b: jax.jit(jax.grad(lambda f, d, b=b: loss(f, d, b), argnums=(0, 1)))(fields, jnp.zeros(6))
             for b in ("xla", "pallas")}
    names = ("means", "log_scales", "logit_opacities", "rgb", "pose")
    flat = {b: list(grads[b][0]) + [grads[b][1]] for b in grads}
    errors = {}
    for name, x, y in zip(names, flat["xla"], flat["pallas"]):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        errors[name] = float(np.abs(x - y).max() / np.abs(x).max())
    _report(dict(test="gradients", cbknn=cbknn is not None, errors=errors))
    for name, err in errors.items():
        assert err <= GRAD_TOL, f"{name}: {err:.2e}"
