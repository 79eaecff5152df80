"""CB-KNN (``render(..., cbknn=CBKNN(...), motion=gamma)``) against the float64 reference ``reference_cbknn.py``.

The reference is written from the contract (method_spec D.4-D.7 as stated in ``gsjax.raster.cbknn``'s docstrings),
on top of the canonical reference walk of ``reference_render.py``; it does not look at the implementation. Run
with ``-s`` to see the measured errors. Pixels where the reference flags a float32-ambiguous decision (the
canonical ones, a top_weight tie at the K-th weight, a unit direction from |C_p - u_k| < 0.01 px) are left out.

Parameter sets: ``FIXED`` (beta = 0: K = round(k0) = 5 everywhere) and ``ADAPTIVE`` (k0 = 4.3, beta = 0.37,
motion 0.83: K in {5, 6, 8, 16} across the cells of the sparse scenes); values chosen off the rounding half points
(checked by the reference).
"""

from __future__ import annotations

import dataclasses
import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import reference_cbknn as rc
import reference_render as rr
import scenes
from gsjax.camera import make_intrinsics, se3_exp
from gsjax.gaussians import Gaussians
from raster_helpers import assert_within_tolerance, errors, format_errors, raster, settings

FIXED = dict(alpha=0.2, k0=5.0, beta=0.0, motion=0.0)
ADAPTIVE = dict(alpha=0.25, k0=4.3, beta=0.37, motion=0.83)
FRACTION_ALPHA = 0.3  # fraction mode: alpha is a fraction of the distance to the centroid
AGREEMENT_SCENES = ("sparse_random", "dense_surface", "heavy_overlap", "rotated_camera")


def cbknn_module():
    return importlib.import_module("gsjax.raster.cbknn")


def make_cbknn(**fields):
    return cbknn_module().CBKNN(**fields)


def split(params: dict) -> tuple[dict, float]:
    """A parameter set -> (traced CBKNN fields, motion)."""
    params = dict(params)
    motion = params.pop("motion")
    return params, motion


def render_cbknn(gaussians, w2c, intr, params: dict, render_settings=None, **static):
    fields, motion = split(params)
    return raster().render(
        gaussians, w2c, intr, render_settings or settings(), cbknn=make_cbknn(**fields, **static), motion=motion
    )


def reference_cbknn(gaussians, w2c, intr, params: dict, render_settings=None, **static):
    fields, motion = split(params)
    s = render_settings or settings()
    return rc.render_cbknn_reference(
        gaussians, w2c, intr, **fields, motion=motion, **static, near=float(s.near), max_contributors=s.max_contributors
    )


_scenes: dict[str, tuple] = {}


def scene(name: str):
    """(gaussians, w2c, intrinsics, canonical reference), built once per session."""
    if name not in _scenes:
        gaussians, w2c, intr = scenes.SCENES[name](0)
        _scenes[name] = (gaussians, w2c, intr, rr.render_reference(gaussians, w2c, intr))
    return _scenes[name]


_pairs: dict[tuple, tuple] = {}


def render_and_reference(name: str, params_name: str, **static):
    """(render, reference) of a scene under FIXED / ADAPTIVE with static flags, cached per session."""
    key = (name, params_name, tuple(sorted(static.items())))
    if key not in _pairs:
        gaussians, w2c, intr, _ = scene(name)
        params = dict(FIXED=FIXED, ADAPTIVE=ADAPTIVE)[params_name]
        if static.get("shift_mode") == "fraction":
            params = dict(params, alpha=FRACTION_ALPHA)
        _pairs[key] = (
            render_cbknn(gaussians, w2c, intr, params, **static),
            reference_cbknn(gaussians, w2c, intr, params, **static),
        )
    return _pairs[key]


def max_abs_difference(a, b) -> float:
    return max(float(np.abs(np.asarray(getattr(a, k), np.float64) - np.asarray(getattr(b, k))).max())
               for k in ("color", "depth", "silhouette", "depth_sq"))


# ----------------------------------------------------------------------------------------------- agreement

CASES = {
    "fixed-first_k-unit-hybrid": ("FIXED", dict()),
    "adaptive-first_k-unit-hybrid": ("ADAPTIVE", dict()),
    "adaptive-top_weight-unit-hybrid": ("ADAPTIVE", dict(select="top_weight")),
    "adaptive-first_k-fraction-hybrid": ("ADAPTIVE", dict(shift_mode="fraction")),
    "adaptive-first_k-unit-truncate": ("ADAPTIVE", dict(truncate=True)),
    "adaptive-top_weight-fraction-truncate": ("ADAPTIVE", dict(select="top_weight", shift_mode="fraction", truncate=True)),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("name", AGREEMENT_SCENES)
def test_cbknn_render_matches_the_float64_reference(name, case):
    params_name, static = CASES[case]
    out, ref = render_and_reference(name, params_name, **static)
    gaussians, w2c, intr, canonical = scene(name)
    valid = ~ref.ambiguous
    errs = errors(out, ref, valid)
    k_values = np.unique(ref.k_pixel)
    print(
        f"\n{format_errors(f'{name} {case}', errs)}\n  K values {k_values.tolist()}, ambiguous px "
        f"{int(ref.ambiguous.sum())}, change vs canonical {max_abs_difference(out, canonical):.3f}, "
        f"pixels with fewer contributors than K {ref.fraction_fewer_than_k:.2f}"
    )
    assert ref.ambiguous.mean() < 0.01
    if ref.kernel is not None:
        assert not ref.kernel.ambiguous, ref.kernel.ambiguous
        np.testing.assert_array_equal(np.asarray(out.stats.cbknn.k_map), ref.kernel.k, err_msg="K map")
        if params_name == "ADAPTIVE" and name != "dense_surface":  # dense_surface: rho = 1 in every cell
            assert len(k_values) >= 3, f"the K map should vary across cells: {k_values}"
    # the smoothing changes the image, so agreement is not agreement with the canonical render
    assert max_abs_difference(out, canonical) > 1e-2
    assert_within_tolerance(f"{name} {case}", errs)


# ----------------------------------------------------------------------------------------------- stats


@pytest.mark.parametrize("name", AGREEMENT_SCENES)
def test_k_map_rho_map_and_fewer_than_k_fraction_match_the_reference(name):
    out, ref = render_and_reference(name, "ADAPTIVE")
    stats = out.stats.cbknn
    h, w = ref.k_pixel.shape
    assert stats.k_map.shape == (-(-h // 8), -(-w // 8)) and stats.k_map.dtype == np.int32
    assert stats.rho_map.shape == stats.k_map.shape and stats.rho_map.dtype == np.float32
    np.testing.assert_array_equal(np.asarray(stats.k_map), ref.kernel.k)
    np.testing.assert_allclose(np.asarray(stats.rho_map), ref.kernel.rho, rtol=1e-5, atol=1e-6)
    slack = (ref.ambiguous.sum() + 1) / (h * w)
    assert abs(float(stats.fraction_fewer_than_k) - ref.fraction_fewer_than_k) <= slack
    print(f"\n{name}: counts per cell\n{ref.kernel.counts}\nK\n{ref.kernel.k}\nfewer than K {ref.fraction_fewer_than_k}")


MEAN_SHIFT_DISAGREEMENT = (
    "mean_shift_px also averages the corrected slots of the padding pixels past the image border (the tile grid "
    "rounds 45 x 60 up to 48 x 64). rotated_camera, ADAPTIVE: unit got 0.240567, the image's corrected slots give "
    "0.241828; fraction got 1.577987, expected 1.599381. The values got are what the reference gives for a 48 x 64 "
    "image with the same K map"
)


@pytest.mark.parametrize(
    "name",
    [
        "sparse_random",
        "heavy_overlap",
        "dense_surface",
        pytest.param("rotated_camera", marks=pytest.mark.xfail(strict=True, reason=MEAN_SHIFT_DISAGREEMENT)),
    ],
)
@pytest.mark.parametrize("shift_mode", ["unit", "fraction"])
def test_mean_shift_px_is_the_mean_over_the_images_corrected_slots(name, shift_mode):
    out, ref = render_and_reference(name, "ADAPTIVE", shift_mode=shift_mode)
    got = float(out.stats.cbknn.mean_shift_px)
    print(f"\n{name} {shift_mode}: mean_shift_px {got:.6f}, reference {ref.mean_shift_px:.6f}")
    np.testing.assert_allclose(got, ref.mean_shift_px, rtol=1e-5)


def test_mean_shift_px_is_alpha_in_unit_mode_when_no_slot_sits_on_its_centroid():
    # heavy_overlap: every pixel has >= 25 contributors, so every G_p has K_p >= 5 slots spread over the layers
    out, ref = render_and_reference("heavy_overlap", "ADAPTIVE")
    assert ref.in_group.sum(-1).min() >= 5
    assert ref.centroid_distance[ref.in_group].min() > 0.05  # |u' - u| = alpha |C - u| / (|C - u| + eps) ~ alpha
    np.testing.assert_allclose(float(out.stats.cbknn.mean_shift_px), ADAPTIVE["alpha"], rtol=1e-5)


@pytest.mark.xfail(
    strict=True,
    reason="mean_shift_px depends on the tile size: sparse_random, ADAPTIVE, unit: 0.250000 with 8-px tiles, 0.247622 "
    "with 16-px tiles (the 16-px grid covers 32 x 48 px; 0.247622 is the reference's mean over a 32 x 48 image, "
    "i.e. it counts the slots of the padding columns 40-47); the images agree with the reference for both",
)
def test_mean_shift_px_does_not_depend_on_the_tile_size():
    # 32 x 40 is a multiple of 8 but not of 16: with 16-px tiles the tile grid covers 32 x 48 pixels
    gaussians, w2c, intr, _ = scene("sparse_random")
    default, ref = render_and_reference("sparse_random", "ADAPTIVE")
    out = render_cbknn(gaussians, w2c, intr, ADAPTIVE, settings(tile_size=16))
    errs = errors(out, ref, ~ref.ambiguous)
    assert_within_tolerance("tile 16", errs)
    np.testing.assert_array_equal(np.asarray(out.stats.cbknn.k_map), np.asarray(default.stats.cbknn.k_map))
    np.testing.assert_allclose(
        float(out.stats.cbknn.mean_shift_px), float(default.stats.cbknn.mean_shift_px), rtol=1e-5
    )
