"""Bad input to ``render`` (and ``make_intrinsics``) raises a ValueError that names the bad argument.

Documented behaviour: shapes, dtypes and image sizes are always checked (they are static, so also under an outer
``jax.jit``); value checks (NaN in an active slot's mean, a non-rigid pose, focal lengths) need concrete
arrays and are skipped when the call is traced.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.gaussians import Gaussians
from gsjax.raster import RasterSettings, render
from tests.support import scenes


@pytest.fixture(scope="module")
def scene():
    return scenes.sparse_random(0)


def render_eager(gaussians, w2c, intr):
    return render(gaussians, w2c, intr, RasterSettings())


def render_jitted(gaussians, w2c, intr):
    s = RasterSettings()
    return jax.jit(lambda g, w, k: render(g, w, k, s))(gaussians, w2c, intr)


BAD_FIELDS = {
    "means [N, 2]": ("means", lambda g: g.means[:, :2]),
    "means [N, 3, 1]": ("means", lambda g: g.means[:, :, None]),
    "means int32": ("means", lambda g: g.means.astype(jnp.int32)),
    "log_scales [N, 1]": ("log_scales", lambda g: g.log_scales[:, None]),
    "log_scales [N + 1]": ("log_scales", lambda g: jnp.append(g.log_scales, 0.0)),
    "log_scales int32": ("log_scales", lambda g: g.log_scales.astype(jnp.int32)),
    "logit_opacities [N - 1]": ("logit_opacities", lambda g: g.logit_opacities[1:]),
    "logit_opacities bool": ("logit_opacities", lambda g: g.logit_opacities > 0),
    "rgb [N, 4]": ("rgb", lambda g: jnp.pad(g.rgb, ((0, 0), (0, 1)))),
    "rgb [N]": ("rgb", lambda g: g.rgb[:, 0]),
    "rgb int32": ("rgb", lambda g: g.rgb.astype(jnp.int32)),
    "active [N + 1]": ("active", lambda g: jnp.append(g.active, True)),
    "active float32": ("active", lambda g: g.active.astype(jnp.float32)),
    "active int32": ("active", lambda g: g.active.astype(jnp.int32)),
}


@pytest.mark.parametrize("call", [render_eager, render_jitted], ids=["eager", "jit"])
@pytest.mark.parametrize("case", sorted(BAD_FIELDS))
def test_malformed_gaussian_field_is_named_in_the_error(scene, case, call):
    gaussians, w2c, intr = scene
    field, corrupt = BAD_FIELDS[case]
    bad = dataclasses.replace(gaussians, **{field: corrupt(gaussians)})
    with pytest.raises(ValueError, match=field):
        call(bad, w2c, intr)


def test_nan_in_an_active_mean_is_named_in_the_error(scene):
    gaussians, w2c, intr = scene
    slot = int(np.flatnonzero(np.asarray(gaussians.active))[3])
    bad = dataclasses.replace(gaussians, means=gaussians.means.at[slot, 1].set(jnp.nan))
    with pytest.raises(ValueError, match="means"):
        render_eager(bad, w2c, intr)


def test_nan_in_an_active_mean_is_not_checked_under_jit(scene):
    gaussians, w2c, intr = scene
    slot = int(np.flatnonzero(np.asarray(gaussians.active))[3])
    bad = dataclasses.replace(gaussians, means=gaussians.means.at[slot, 1].set(jnp.nan))
    out = render_jitted(bad, w2c, intr)  # documented: value checks are skipped when traced
    assert out.color.shape == (intr.height, intr.width, 3)


def test_non_rigid_w2c_is_named_in_the_error(scene):
    gaussians, w2c, intr = scene
    scaled = w2c.at[:3, :3].multiply(1.1)
    sheared = w2c.at[0, 1].add(0.2)
    bottom = w2c.at[3, 0].set(0.5)
    reflected = w2c.at[2].multiply(-1.0)
    for bad in (scaled, sheared, bottom, reflected):
        with pytest.raises(ValueError, match="w2c"):
            render_eager(gaussians, bad, intr)
    out = render_jitted(gaussians, scaled, intr)  # not checked when traced
    assert out.color.shape == (intr.height, intr.width, 3)


def test_non_finite_w2c_is_named_in_the_error(scene):
    gaussians, w2c, intr = scene
    for bad in (w2c.at[0, 3].set(jnp.nan), w2c.at[1, 1].set(jnp.inf)):
        with pytest.raises(ValueError, match="w2c"):
            render_eager(gaussians, bad, intr)


@pytest.mark.parametrize("call", [render_eager, render_jitted], ids=["eager", "jit"])
@pytest.mark.parametrize("shape", [(3, 4), (4, 3), (16,), (1, 4, 4)])
def test_w2c_of_the_wrong_shape_is_named_in_the_error(scene, shape, call):
    gaussians, w2c, intr = scene
    bad = {(3, 4): w2c[:3], (4, 3): w2c[:, :3], (16,): w2c.reshape(16), (1, 4, 4): w2c[None]}[shape]
    with pytest.raises(ValueError, match="w2c"):
        call(gaussians, bad, intr)


@pytest.mark.parametrize("name, value", [("fx", 0.0), ("fx", -40.0), ("fy", 0.0), ("fy", -1.0), ("fx", float("nan"))])
def test_non_positive_focal_length_is_named_by_make_intrinsics(name, value):
    args = dict(fx=40.0, fy=40.0, cx=20.0, cy=16.0, height=32, width=40)
    args[name] = value
    with pytest.raises(ValueError, match=name):
        make_intrinsics(**args)


@pytest.mark.parametrize("name, value", [("height", 0), ("height", -32), ("width", 0), ("width", -1), ("width", 2.5)])
def test_non_positive_image_size_is_named_by_make_intrinsics(name, value):
    args = dict(fx=40.0, fy=40.0, cx=20.0, cy=16.0, height=32, width=40)
    args[name] = value
    with pytest.raises(ValueError, match=name):
        make_intrinsics(**args)


def hand_built(**overrides) -> Intrinsics:
    """Intrinsics that bypass make_intrinsics' checks."""
    values = dict(fx=36.0, fy=36.0, cx=19.3, cy=15.6, height=scenes.HEIGHT, width=scenes.WIDTH)
    values.update(overrides)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    fx, fy, cx, cy = (f32(values[k]) for k in ("fx", "fy", "cx", "cy"))
    return Intrinsics(fx, fy, cx, cy, values["height"], values["width"])


@pytest.mark.parametrize("name, value", [("fx", 0.0), ("fx", -36.0), ("fy", 0.0), ("fy", -2.0)])
def test_non_positive_focal_length_is_named_by_render(scene, name, value):
    gaussians, w2c, _ = scene
    with pytest.raises(ValueError, match=name):
        render_eager(gaussians, w2c, hand_built(**{name: value}))


@pytest.mark.parametrize("call", [render_eager, render_jitted], ids=["eager", "jit"])
@pytest.mark.parametrize("name, value", [("height", 0), ("height", -4), ("width", 0), ("width", -40)])
def test_non_positive_image_size_is_named_by_render(scene, name, value, call):
    # height and width are static (they set array shapes), so they are checked under jit as well
    gaussians, w2c, _ = scene
    with pytest.raises(ValueError, match=name):
        call(gaussians, w2c, hand_built(**{name: value}))


@pytest.mark.parametrize("field, value", [("near", 0.0), ("near", float("nan")), ("dilation", -0.1),
                                          ("dilation", float("inf"))])
def test_bad_traced_raster_settings_are_named(field, value):

    with pytest.raises(ValueError, match=f"RasterSettings.{field} must be"):
        RasterSettings(**{field: value})


def test_valid_input_passes_the_checks():
    # the checks above are not triggered by a good map, even one with garbage in its free slots
    gaussians, w2c, intr = scenes.inactive_garbage(0)
    assert isinstance(gaussians, Gaussians) and not np.asarray(gaussians.active).all()
    out = render_eager(gaussians, w2c, intr)
    assert np.isfinite(np.asarray(out.color)).all()


def test_concrete_arguments_closed_over_by_an_outer_jit_are_accepted(scene):
    # Inside a traced function, closed-over concrete arrays are still concrete, but any jnp operation on them
    # yields a tracer: value checks must not turn them into tracers and then ask for a Python bool or float.
    gaussians, w2c, intr = scene
    s = RasterSettings()
    eager = render(gaussians, w2c, intr, s)
    failures = []
    for label, fn, arg in (
        ("w2c closed over", lambda g: render(g, w2c, intr, s), gaussians),
        ("gaussians closed over", lambda w: render(gaussians, w, intr, s), w2c),
        ("only intrinsics closed over", lambda args: render(args[0], args[1], intr, s), (gaussians, w2c)),
    ):
        try:
            out = jax.jit(fn)(arg)
        except Exception as error:
            failures.append(f"{label}: {type(error).__name__}: {str(error).splitlines()[0]}")
            continue
        np.testing.assert_allclose(np.asarray(out.color), np.asarray(eager.color), atol=1e-5, err_msg=label)
    assert not failures, "\n".join(failures)
