"""Contributor slots chosen at one pose and composited at another (``select_slots``, ``render(...,
selection=...)``): at its own pose a selection is the render bit for bit; at a nearby pose it composites exactly
its slots (against a float64 reference that blends a fixed contributor set), with the pose gradient of that
composite; the strided grids' slots are the full image's at their pixels."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import se3_exp
from gsjax.raster import RasterSettings, SlotSelection, render, select_slots
from gsjax.raster.binning import TileGrid
from gsjax.raster.cbknn import CBKNN
from gsjax.raster.render import strided_selection
from tests.support import reference_render as rr
from tests.support import scenes
from tests.support.raster_checks import GRAD_SEED, OUTPUTS, REL_TOL, STEP, assert_within_tolerance, errors, loss_weights

MOVE = np.array([0.02, -0.015, 0.01, 0.02, -0.01, 0.015])  # 2 cm and ~1.5 degrees: contributor sets change


@jax.jit
def _fresh_and_reused(g, w2c, intr, settings, cbknn):
    selection = select_slots(g, w2c, intr, settings)
    return render(g, w2c, intr, settings, cbknn), render(g, w2c, intr, settings, cbknn, selection=selection)


@pytest.mark.parametrize("name", ["dense_surface", "heavy_overlap", "off_screen"])
@pytest.mark.parametrize("variant", ["canonical", "pose_only", "cbknn"])
def test_a_selection_composited_at_its_own_pose_is_the_render(name, variant):
    gaussians, w2c, intr = scenes.SCENES[name](0)
    settings = RasterSettings(pose_only=variant == "pose_only")
    cbknn = CBKNN(alpha=0.3, k0=4.0, beta=0.3) if variant == "cbknn" else None
    fresh, reused = _fresh_and_reused(gaussians, w2c, intr, settings, cbknn)
    for field in OUTPUTS:
        np.testing.assert_array_equal(np.asarray(getattr(reused, field)), np.asarray(getattr(fresh, field)), field)
    for field in ("tiles_overflowed", "intersections_dropped", "pixels_out_of_k", "pixels_truncated",
                  "max_residual_transmittance", "max_contributors"):
        assert float(getattr(reused.stats, field)) == float(getattr(fresh.stats, field)), field


def _loss(delta, gaussians, w2c0, intr, weights, selection):
    out = render(gaussians, se3_exp(delta) @ w2c0, intr, RasterSettings(pose_only=True), selection=selection)
    return sum(jnp.sum(getattr(out, k) * w) for k, w in weights.items())


_loss_and_grad = jax.jit(jax.value_and_grad(_loss))


@pytest.mark.parametrize("name", sorted(scenes.GRADIENT_SCENES))
def test_a_stale_selection_composites_its_slots_at_the_new_pose_with_the_pose_gradient(name):
    """Slots chosen at ``w2c`` and composited at exp(MOVE) ``w2c``: the float64 reference blending the reference's
    contributors at ``w2c`` (in that depth order, with the new pose's alphas); the pose gradient against its central
    finite differences. The move changes the contributor sets, so the stale render is not the fresh one."""
    gaussians, w2c, intr = scenes.GRADIENT_SCENES[name](GRAD_SEED)
    moved = np.asarray(se3_exp(jnp.asarray(MOVE, jnp.float32)) @ w2c, np.float64)
    selection = select_slots(gaussians, w2c, intr, RasterSettings())
    stale = render(gaussians, jnp.asarray(moved, jnp.float32), intr, RasterSettings(), selection=selection)

    g64 = rr.render_reference(gaussians, np.asarray(w2c, np.float64), intr)  # the contributors at w2c
    assert not g64.ambiguous.any()
    reference = rr.composite_reference(gaussians, moved, intr, g64.contributors, g64.order)
    assert_within_tolerance(f"{name} stale selection", errors(stale, reference))
    fresh = rr.render_reference(gaussians, moved, intr)
    assert not np.array_equal(fresh.contributors, g64.contributors), "the move changed no contributor set"

    weights = loss_weights(intr.height, intr.width)
    weights32 = {k: jnp.asarray(v, jnp.float32) for k, v in weights.items()}
    moved32 = jnp.asarray(moved, jnp.float32)
    _, grad = _loss_and_grad(jnp.zeros(6, jnp.float32), gaussians, moved32, intr, weights32, selection)
    direction, h = np.random.default_rng(5).normal(size=6), STEP["pose"]

    def reference_loss(sign):
        at = scenes.se3_exp_np(sign * h * direction) @ moved
        out = rr.composite_reference(gaussians, at, intr, g64.contributors, g64.order)
        return sum(np.sum(getattr(out, k) * w) for k, w in weights.items())

    finite_difference = (reference_loss(1.0) - reference_loss(-1.0)) / (2 * h)
    by_grad = float(np.sum(np.asarray(grad, np.float64) * direction))
    assert abs(finite_difference) > 1e-3
    assert abs(by_grad - finite_difference) <= REL_TOL * abs(finite_difference), (by_grad, finite_difference)


@pytest.mark.parametrize("height, width", [(32, 40), (29, 39)])
def test_the_strided_grids_slots_are_the_full_images_at_their_pixels(height, width):
    """``strided_selection`` lays the full image's slots at pixels (2 i + row, 2 j + col) out on the strided tile
    grid, also for odd image sizes (whose strided tile grids are not the full grid's). At even sizes that is what
    selecting on the strided grid itself gives (the strided render at a quarter of the dilation is the full render's
    pixels; at odd sizes the Jacobian clamp's field of view differs by half a pixel)."""
    gaussians, w2c, intr = scenes.SCENES["dense_surface"](0)
    intr = dataclasses.replace(intr, height=height, width=width)
    full = RasterSettings(tile_size=8)
    strided = RasterSettings(tile_size=4, dilation=full.dilation / 4.0)
    selection = select_slots(gaussians, w2c, intr, full)
    full_ids = np.moveaxis(np.asarray(TileGrid.for_image(height, width, 8).untile(selection.ids.T)), -1, 0)
    part = TileGrid.for_image(height // 2, width // 2, 4)
    for row in (0, 1):
        for col in (0, 1):
            mapped = strided_selection(selection, height, width, 8, 4, jnp.int32(row), jnp.int32(col))
            laid_out = np.moveaxis(np.asarray(part.untile(mapped.ids.T)), -1, 0)
            np.testing.assert_array_equal(laid_out, full_ids[:, row::2, col::2][:, : height // 2, : width // 2])
            assert int(np.sum(laid_out >= 0)) > 0
            if height % 2 == 0 and width % 2 == 0:
                own = select_slots(gaussians, w2c, intr.strided(row, col), strided)
                np.testing.assert_array_equal(np.asarray(mapped.ids), np.asarray(own.ids), f"grid {row}, {col}")
                np.testing.assert_array_equal(np.asarray(mapped.num_kept), np.asarray(own.num_kept))


def test_a_selection_of_another_shape_is_refused():
    gaussians, w2c, intr = scenes.SCENES["sparse_random"](0)
    selection = select_slots(gaussians, w2c, intr, RasterSettings(max_contributors=32))
    with pytest.raises(ValueError, match="selection must be a SlotSelection"):
        render(gaussians, w2c, intr, RasterSettings(), selection=selection)
    with pytest.raises(ValueError, match="selection must be a SlotSelection"):
        render(gaussians, w2c, intr, RasterSettings(), selection=selection.ids)
    assert isinstance(selection, SlotSelection)
