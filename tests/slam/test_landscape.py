"""The pure landscape (:mod:`gsjax.slam.landscape`): the 1-D and 2-D basin criteria recover basins known
analytically (masks drawn from discs, and gradient descent on double wells), the fixed-point errors are measured
from the tracker's own fixed point, and the 2-D grid lies [i, j] = (axis 0 at i, axis 1 at j)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import rotation_angle_np, se3_inverse_np
from gsjax.slam import landscape as pure
from gsjax.slam.tracking import TrackingProblem
from tests.support.tiny_slam import first_frame_map, map_config, relative_gt_w2c, replaced, tiny_sequence

# ------------------------------------------------------------------------------------------------ basin criteria


@pytest.mark.parametrize("steps", [20, 21])
@pytest.mark.parametrize("radius", [0.23, 0.55, 0.87])
@pytest.mark.parametrize("extents", [(4.0, 4.0), (1.0, 3.0)])
def test_the_2d_basin_of_an_elliptic_mask_is_its_radius_within_a_grid_step(steps, radius, extents):
    """Converged exactly inside the ellipse (a / e_a)^2 + (b / e_b)^2 <= r^2: the basin is r, less at most one grid
    step (2 / (steps - 1) of the half-width), and the area the ellipse's share of the grid's points."""
    a, b = (np.linspace(-e, e, steps) for e in extents)
    inside = np.hypot(a[:, None] / extents[0], b[None, :] / extents[1]) <= radius
    basin, area = pure.basin_2d(a, b, inside)
    assert radius - 2 / (steps - 1) < basin <= radius
    assert area == pytest.approx(inside.mean())


def test_the_2d_basin_is_the_largest_disc_about_the_reference_inside_an_off_centre_basin():
    """Converged inside a disc of radius R centred at c != 0 (normalised units): the basin about the reference is
    R - |c|, not R, within a grid step (either way: the nearest grid point outside the disc may lie beyond R - |c|)."""
    a = b = np.linspace(-2.0, 2.0, 41)
    centre, disc = np.array([0.25, -0.2]), 0.7
    inside = np.hypot(a[:, None] / 2 - centre[0], b[None, :] / 2 - centre[1]) <= disc
    basin, _ = pure.basin_2d(a, b, inside)
    expected = disc - np.hypot(*centre)
    assert abs(basin - expected) < 2 / 40


def test_the_2d_basin_stops_at_one_failure_and_spans_at_most_the_inscribed_ellipse():
    a, b = np.linspace(-1, 1, 11), np.linspace(-3, 3, 11)
    everywhere = np.ones((11, 11), bool)
    assert pure.basin_2d(a, b, everywhere) == (1.0, 1.0)  # the corners (radius sqrt 2) are outside the ellipse
    one_off = everywhere.copy()
    one_off[7, 5] = False  # a = 0.4, b = 0: radius 0.4; the nearest points inside are at 0.2 * sqrt(2) and 0.2
    assert pure.basin_2d(a, b, one_off) == (pytest.approx(0.2 * np.sqrt(2)), pytest.approx(120 / 121))
    centre_fails = everywhere.copy()
    centre_fails[5, 5] = False
    assert pure.basin_2d(a, b, centre_fails)[0] == 0.0


def _descend(loss, starts: np.ndarray, lr: float, steps: int) -> np.ndarray:
    """Plain gradient descent on ``loss`` from every start [N, D] -> the final points [N, D]."""
    step = jax.grad(loss)

    @jax.jit
    def run(x):
        return jax.lax.fori_loop(0, steps, lambda _, x: x - lr * step(x), x)

    return np.asarray(jax.vmap(run)(jnp.asarray(starts, jnp.float32)))


def test_the_1d_basin_of_gradient_descent_on_a_double_well_is_its_nearer_boundary():
    """f(x) = x^2 (x - w)^2 has minima at 0 and w and its maximum at w / 2: descent from x < w / 2 ends at 0, so the
    basin about 0 is w / 2 (bounded on one side only), recovered within a grid step."""
    well = 1.3
    offsets = np.linspace(-2.0, 2.0, 41)
    final = _descend(lambda x: (x[0] * (x[0] - well)) ** 2, offsets[:, None], lr=2e-3, steps=20000)[:, 0]
    converged = np.abs(final) < 1e-3
    np.testing.assert_array_equal(converged, offsets < well / 2)
    assert well / 2 - 0.1 < pure.basin_width(offsets, converged) <= well / 2


def test_the_2d_basin_of_gradient_descent_on_an_elliptic_double_well_is_its_ridge():
    """f = s (s - 3 r^2)^2 in s = (x / e_x)^2 + (y / e_y)^2: descent ends at 0 from inside the ridge s = r^2 (the
    ellipse of normalised radius r) and on the ring s = 3 r^2 from outside; the 2-D basin recovers r within a grid
    step, and the converged mask the ellipse except within a step of its boundary."""
    radius, extents, steps = 0.55, (4.0, 2.0), 21
    x, y = (np.linspace(-e, e, steps) for e in extents)

    def loss(p):
        s = (p[0] / extents[0]) ** 2 + (p[1] / extents[1]) ** 2
        return s * (s - 3 * radius**2) ** 2

    starts = np.stack(np.meshgrid(x, y, indexing="ij"), -1).reshape(-1, 2)
    final = _descend(loss, starts, lr=0.05, steps=10000).reshape(steps, steps, 2)
    converged = np.hypot(final[..., 0] / extents[0], final[..., 1] / extents[1]) < 1e-3
    radii = pure.normalised_radii(x, y)
    far = np.abs(radii - radius) > 2 / (steps - 1)
    np.testing.assert_array_equal(converged[far], (radii < radius)[far])
    basin, area = pure.basin_2d(x, y, converged)
    assert radius - 2 / (steps - 1) < basin <= radius
    assert area == pytest.approx(converged.mean()) and 0 < area < 1


def test_map_batched_equals_the_map_for_any_batch():
    for n in (1, 5, 7):
        xs = jnp.arange(3.0 * n).reshape(n, 3)
        for batch in (None, 1, 2, 3, 100):
            total, doubled = pure.map_batched(lambda v: (v.sum(), 2 * v), xs, batch)
            np.testing.assert_array_equal(total, xs.sum(1))
            np.testing.assert_array_equal(doubled, 2 * xs)


# ----------------------------------------------------------------------------- the tracker's landscape, tiny map

AXES = ("tx", "rz")
OFFSETS = np.array([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0]], np.float32)  # cm, deg: unequal, so a transpose shows
MID = 1


@functools.lru_cache(maxsize=None)
def _landscapes():
    """(the landscape with the tracker standing still (step size 0), the same with it moving, the reference): frame
    1 tracked on the map of frame 0 from its ground-truth pose, along and over tx x rz. Both with one program (the
    step sizes are traced)."""
    config = replaced(map_config(), {"tracking.iters": 5})
    w2c_ref = jnp.asarray(relative_gt_w2c()[1], jnp.float32)
    frame = tiny_sequence()[1]
    problem = TrackingProblem(first_frame_map(), frame.color, frame.depth, w2c_ref, tiny_sequence().intrinsics,
                              jnp.bool_(False), jnp.float32(0.0))
    run = functools.partial(pure.landscape, problem, directions=pure.directions(AXES), offsets=jnp.asarray(OFFSETS),
                            plane=True, batch=1)  # one point at a time (as on a CPU): faster to compile
    still = replaced(config, {"tracking.lr_trans": 0.0, "tracking.lr_rot": 0.0})
    return jax.device_get(run(config=still)), jax.device_get(run(config=config)), np.asarray(w2c_ref)


def _error(w2c, w2c_ref):
    """(cm, deg) of w2c [..., 4, 4] from w2c_ref, in float64."""
    relative = np.asarray(w2c, np.float64) @ se3_inverse_np(np.asarray(w2c_ref, np.float64))
    return 100 * np.linalg.norm(relative[..., :3, 3], axis=-1), np.degrees(rotation_angle_np(relative[..., :3, :3]))


def test_when_the_tracker_stands_still_the_fixed_point_is_the_reference_and_both_errors_are_the_offsets():
    still, _, w2c_ref = _landscapes()
    np.testing.assert_allclose(still.fixed_w2c, w2c_ref, atol=1e-6)
    for part in (still, still.plane):
        np.testing.assert_allclose(part.fixed_error_cm, part.error_cm, atol=1e-4)
        np.testing.assert_allclose(part.fixed_error_deg, part.error_deg, atol=1e-3)
    # Along tx only translation, along rz only rotation; over the plane [i, j] = (tx_i, rz_j).
    np.testing.assert_allclose(still.error_cm[0], np.abs(OFFSETS[0]), atol=1e-4)
    np.testing.assert_allclose(still.error_deg[1], np.abs(OFFSETS[1]), atol=2e-3)
    np.testing.assert_allclose(still.plane.error_deg, np.broadcast_to(np.abs(OFFSETS[1]), (3, 3)), atol=2e-3)
    # exp(rho, phi) translates by V(phi) rho, |V(phi) rho| within (phi / 2)^2 of |rho|.
    np.testing.assert_allclose(still.plane.error_cm, np.broadcast_to(np.abs(OFFSETS[0])[:, None], (3, 3)), rtol=1e-3,
                               atol=1e-4)


def test_the_plane_through_the_reference_holds_the_axes_own_landscapes():
    """Grid point (tx_i, 0) is the point tx_i of the tx axis, and (0, rz_j) the point rz_j of the rz axis: the same
    loss, the same gradient along the axis."""
    _, moving, _ = _landscapes()
    np.testing.assert_allclose(moving.plane.loss[:, MID], moving.loss[0], rtol=1e-5)
    np.testing.assert_allclose(moving.plane.loss[MID, :], moving.loss[1], rtol=1e-5)
    np.testing.assert_allclose(moving.plane.grad[:, MID, 0], moving.grad[0], rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(moving.plane.grad[MID, :, 1], moving.grad[1], rtol=1e-4, atol=1e-3)
    assert np.ptp(moving.loss[0]) > 0 and np.ptp(moving.loss[1]) > 0  # the comparison sees the offsets


def test_errors_are_measured_from_the_reference_and_fixed_errors_from_where_the_tracker_from_it_ends():
    """The tracker started at the reference ends away from it (the map of frame 0 is not frame 1's scene): that
    is the fixed point; every final pose's error is its distance from the reference, its fixed error the distance
    from the fixed point. Swapping them fails: the two differ by the fixed point's own distance."""
    _, moving, w2c_ref = _landscapes()
    # The grid points at offset 0 are the reference: the tracker from there is the fixed point.
    for axis in range(len(AXES)):
        np.testing.assert_allclose(moving.final_w2c[axis, MID], moving.fixed_w2c, atol=1e-6)
    bias_cm, bias_deg = _error(moving.fixed_w2c, w2c_ref)
    assert bias_cm > 0.05
    for part in (moving, moving.plane):
        for (cm, deg), target in (((part.error_cm, part.error_deg), w2c_ref),
                                  ((part.fixed_error_cm, part.fixed_error_deg), moving.fixed_w2c)):
            expected_cm, expected_deg = _error(part.final_w2c, target)
            np.testing.assert_allclose(cm, expected_cm, atol=2e-3)
            np.testing.assert_allclose(deg, expected_deg, atol=2e-2)
    np.testing.assert_allclose(moving.fixed_error_cm[:, MID], 0.0, atol=2e-3)
    np.testing.assert_allclose(moving.error_cm[:, MID], bias_cm, atol=2e-3)
