"""Property tests of gsjax.camera over random transforms (fixed numpy seeds), in the spirit of jaxlie's
``test_group_axioms.py``: group axioms, exp/log round trips, Jacobians against finite differences, and the
projection conventions. Independent references come from scipy's matrix exponential in float64.

gsjax computes in float32 here (x64 is off), so tolerances are float32-sized.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from gsjax.camera import (
    Intrinsics,
    backproject,
    camera_center,
    constant_velocity,
    make_intrinsics,
    perturb_left,
    project_points,
    quaternion_to_rotation,
    quaternion_to_rotation_np,
    rigidity_error,
    rotation_angle,
    rotation_angle_np,
    rotation_to_quaternion,
    rotation_to_quaternion_np,
    se3_exp,
    se3_inverse,
    se3_inverse_np,
    se3_log,
    so3_exp,
    so3_log,
)

N_SAMPLES = 64
v_se3_exp = jax.jit(jax.vmap(se3_exp))
v_se3_log = jax.jit(jax.vmap(se3_log))
v_so3_exp = jax.jit(jax.vmap(so3_exp))
v_so3_log = jax.jit(jax.vmap(so3_log))


def hat_np(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def expm_se3(delta) -> np.ndarray:
    """float64 reference: the matrix exponential of the 4x4 twist [[hat(phi), rho], [0, 0]]."""
    delta = np.asarray(delta, np.float64)
    twist = np.zeros((4, 4))
    twist[:3, :3], twist[:3, 3] = hat_np(delta[3:]), delta[:3]
    return scipy.linalg.expm(twist)


def random_tangents(seed: int, n: int = N_SAMPLES, angles=(0.0, 3.0), translation: float = 2.0) -> np.ndarray:
    """[n, 6] tangents (rho, phi) with rotation angles uniform in ``angles`` (rad)."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    phi = axis * rng.uniform(*angles, (n, 1))
    return np.concatenate([rng.uniform(-translation, translation, (n, 3)), phi], axis=1)


# Angle regimes: generic, tiny, around the Taylor-series switch (theta^2 = 0.04), close to pi.
REGIMES = {
    "generic": dict(angles=(0.0, 3.0)),
    "tiny": dict(angles=(1e-8, 1e-6), translation=1e-6),
    "taylor_switch": dict(angles=(0.19, 0.21)),
    "near_pi": dict(angles=(3.0, 3.13)),
}


@pytest.mark.parametrize("regime", sorted(REGIMES))
def test_se3_exp_is_the_matrix_exponential_of_the_twist(regime):
    deltas = random_tangents(1, **REGIMES[regime])
    got = np.asarray(v_se3_exp(jnp.asarray(deltas, jnp.float32)), np.float64)
    want = np.stack([expm_se3(d) for d in deltas])
    # compare the deviation from the identity so that tiny tangents are checked relative to their size
    scale = np.maximum(np.abs(deltas).max(axis=1), 1e-30)[:, None, None]
    eye = np.eye(4)
    np.testing.assert_allclose((got - eye) / scale, (want - eye) / scale, atol=2e-5 if regime == "tiny" else 1e-5)


@pytest.mark.parametrize("regime", sorted(REGIMES))
def test_se3_log_inverts_se3_exp(regime):
    deltas = random_tangents(2, **REGIMES[regime])
    back = np.asarray(v_se3_log(v_se3_exp(jnp.asarray(deltas, jnp.float32))), np.float64)
    scale = np.abs(deltas).max(axis=1, keepdims=True)
    # near pi the log is ill-conditioned in float32 (d angle ~ eps / sin(theta))
    tol = {"near_pi": 2e-3, "generic": 5e-5}.get(regime, 1e-5)
    np.testing.assert_allclose(back / scale, deltas / scale, atol=tol)


@pytest.mark.parametrize("regime", sorted(REGIMES))
def test_se3_exp_of_se3_log_is_the_identity_map_on_transforms(regime):
    transforms = np.stack([expm_se3(d) for d in random_tangents(3, **REGIMES[regime])])
    t32 = jnp.asarray(transforms, jnp.float32)
    again = np.asarray(v_se3_exp(v_se3_log(t32)), np.float64)
    np.testing.assert_allclose(again, transforms, atol=1e-5)


def test_exp_of_zero_is_the_identity_and_log_of_the_identity_is_zero():
    np.testing.assert_array_equal(np.asarray(v_se3_exp(jnp.zeros((1, 6))))[0], np.eye(4))
    np.testing.assert_array_equal(np.asarray(v_so3_exp(jnp.zeros((1, 3))))[0], np.eye(3))
    np.testing.assert_array_equal(np.asarray(v_se3_log(jnp.eye(4)[None]))[0], np.zeros(6))
    np.testing.assert_array_equal(np.asarray(v_so3_log(jnp.eye(3)[None]))[0], np.zeros(3))


def test_inverse_composes_to_the_identity_and_negates_the_tangent():
    deltas = jnp.asarray(random_tangents(4), jnp.float32)
    transforms = v_se3_exp(deltas)
    inverses = jax.vmap(se3_inverse)(transforms)
    eye = np.broadcast_to(np.eye(4), (N_SAMPLES, 4, 4))
    np.testing.assert_allclose(np.asarray(inverses @ transforms), eye, atol=1e-5)
    np.testing.assert_allclose(np.asarray(transforms @ inverses), eye, atol=1e-5)
    np.testing.assert_allclose(np.asarray(v_se3_exp(-deltas)), np.asarray(inverses), atol=1e-5)
    np.testing.assert_allclose(np.asarray(v_se3_log(inverses)), -np.asarray(deltas), atol=1e-4)


def test_composition_is_associative_and_log_of_a_power_scales_the_tangent():
    a, b, c = (v_se3_exp(jnp.asarray(random_tangents(s), jnp.float32)) for s in (5, 6, 7))
    np.testing.assert_allclose(np.asarray((a @ b) @ c), np.asarray(a @ (b @ c)), atol=2e-5)
    small = jnp.asarray(random_tangents(8, angles=(0.0, 1.0)), jnp.float32)
    half = v_se3_exp(0.5 * small)
    np.testing.assert_allclose(np.asarray(half @ half), np.asarray(v_se3_exp(small)), atol=1e-5)


@pytest.mark.parametrize("regime", sorted(REGIMES))
def test_so3_exp_is_a_proper_rotation_about_its_axis(regime):
    phi = random_tangents(9, **REGIMES[regime])[:, 3:]
    rot = np.asarray(v_so3_exp(jnp.asarray(phi, jnp.float32)), np.float64)
    np.testing.assert_allclose(rot @ np.swapaxes(rot, 1, 2), np.broadcast_to(np.eye(3), rot.shape), atol=2e-6)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=5e-6)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", rot, phi), phi, atol=1e-6 * np.abs(phi).max() + 1e-30)
    want = np.stack([scipy.linalg.expm(hat_np(p)) for p in phi])
    np.testing.assert_allclose(rot, want, atol=2e-6)
    angles = np.asarray(jax.vmap(rotation_angle)(jnp.asarray(rot, jnp.float32)))
    np.testing.assert_allclose(angles, np.linalg.norm(phi, axis=1), atol=2e-3 if regime == "near_pi" else 2e-6)


def test_so3_log_handles_half_turns():
    # rotation by exactly pi: the axis is defined up to sign, so compare the rotations
    for axis in (np.eye(3)[0], np.eye(3)[1], np.eye(3)[2], np.array([1.0, 2.0, -2.0]) / 3.0):
        rot = scipy.linalg.expm(hat_np(np.pi * axis))
        phi = np.asarray(so3_log(jnp.asarray(rot, jnp.float32)), np.float64)
        assert np.isfinite(phi).all()
        np.testing.assert_allclose(np.linalg.norm(phi), np.pi, atol=1e-3)
        np.testing.assert_allclose(scipy.linalg.expm(hat_np(phi)), rot, atol=1e-3)


def test_quaternions_round_trip_through_rotations():
    rng = np.random.default_rng(10)
    quats = rng.normal(size=(N_SAMPLES, 4))
    quats[:4] = np.eye(4)  # identity and the three half turns (one per Shepperd pivot)
    quats[4:8] = np.eye(4) + 1e-3 * rng.normal(size=(4, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    quats *= np.where(quats[:, :1] < 0, -1.0, 1.0)  # canonical: w >= 0
    q32 = jnp.asarray(quats, jnp.float32)
    rot = jax.vmap(quaternion_to_rotation)(q32)
    back = np.asarray(jax.vmap(rotation_to_quaternion)(rot), np.float64)
    # w == 0 exactly (half turns) leaves the sign free: compare up to sign
    sign = np.where(np.sum(back * quats, axis=1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(back * sign, quats, atol=2e-6)
    assert (back[:, 0] >= 0).all()
    np.testing.assert_allclose(np.asarray(jax.vmap(quaternion_to_rotation)(-q32)), np.asarray(rot), atol=1e-6)
    np.testing.assert_allclose(np.asarray(jax.vmap(quaternion_to_rotation)(3.0 * q32)), np.asarray(rot), atol=1e-6)
    # agrees with the axis-angle map: q = (cos(t/2), sin(t/2) axis)
    phi = random_tangents(11)[:, 3:]
    theta = np.linalg.norm(phi, axis=1, keepdims=True)
    want = np.concatenate([np.cos(theta / 2), np.sin(theta / 2) * phi / theta], axis=1)
    got = np.asarray(jax.vmap(rotation_to_quaternion)(v_so3_exp(jnp.asarray(phi, jnp.float32))))
    np.testing.assert_allclose(got, want, atol=2e-6)


def test_perturb_left_multiplies_the_exponential_on_the_left():
    deltas = jnp.asarray(random_tangents(12, angles=(0.0, 0.5), translation=0.2), jnp.float32)
    poses = v_se3_exp(jnp.asarray(random_tangents(13), jnp.float32))
    got = jax.vmap(perturb_left)(deltas, poses)
    np.testing.assert_allclose(np.asarray(got), np.asarray(v_se3_exp(deltas) @ poses), atol=1e-6)
    assert not np.allclose(np.asarray(got), np.asarray(poses @ v_se3_exp(deltas)), atol=1e-2)  # not the right one


def test_small_left_perturbation_moves_camera_points_by_rho_plus_phi_cross_x():
    rng = np.random.default_rng(14)
    pose = jnp.asarray(expm_se3(random_tangents(15, n=1)[0]), jnp.float32)
    world = jnp.asarray(rng.normal(size=3), jnp.float32)

    def camera_point(delta):
        return (perturb_left(delta, pose) @ jnp.append(world, 1.0))[:3]

    camera_point = jax.jit(camera_point)
    x_cam = np.asarray(camera_point(jnp.zeros(6)), np.float64)
    # exact first order: d x_cam / d delta at 0 = [I, -hat(x_cam)]
    jac = np.asarray(jax.jit(jax.jacfwd(camera_point))(jnp.zeros(6)), np.float64)
    np.testing.assert_allclose(jac, np.concatenate([np.eye(3), -hat_np(x_cam)], axis=1), atol=1e-5)
    # and a small finite step: x' = x + rho + phi x x + O(|delta|^2)
    delta = 1e-3 * rng.normal(size=6)
    moved = np.asarray(camera_point(jnp.asarray(delta, jnp.float32)), np.float64)
    first_order = x_cam + delta[:3] + np.cross(delta[3:], x_cam)
    assert np.linalg.norm(moved - first_order) < 10 * np.linalg.norm(delta) ** 2 + 1e-6
    assert np.linalg.norm(moved - x_cam) > 100 * np.linalg.norm(moved - first_order)


def test_se3_exp_jacobian_matches_finite_differences_and_the_generators_at_zero():
    generators = np.stack([expm_se3(1e-8 * e) - np.eye(4) for e in np.eye(6)], axis=-1) / 1e-8  # d exp / d delta_k
    for jacobian in (jax.jit(jax.jacfwd(se3_exp)), jax.jit(jax.jacrev(se3_exp))):
        at_zero = np.asarray(jacobian(jnp.zeros(6)), np.float64)  # [4, 4, 6]
        assert np.isfinite(at_zero).all()
        np.testing.assert_allclose(at_zero, generators, atol=1e-6)
    h = 1e-6
    deltas = random_tangents(16, n=8, angles=(0.05, 2.5))
    got = np.asarray(jax.jit(jax.vmap(jax.jacfwd(se3_exp)))(jnp.asarray(deltas, jnp.float32)), np.float64)
    for delta, jac in zip(deltas, got):
        fd = np.stack([(expm_se3(delta + h * e) - expm_se3(delta - h * e)) / (2 * h) for e in np.eye(6)], axis=-1)
        np.testing.assert_allclose(jac, fd, atol=5e-5 * max(1.0, np.abs(fd).max()))
    # the log's Jacobian at the identity is finite too (the tracking gradient passes through it), and log o exp
    # has the identity Jacobian at zero
    assert np.isfinite(np.asarray(jax.jit(jax.jacfwd(se3_log))(jnp.eye(4)))).all()
    round_trip = jax.jit(jax.jacfwd(lambda d: se3_log(se3_exp(d))))(jnp.zeros(6))
    np.testing.assert_allclose(np.asarray(round_trip), np.eye(6), atol=1e-6)


@pytest.mark.parametrize("frame", ["left", "right"])
def test_constant_velocity_continues_a_constant_twist_sequence(frame):
    start = expm_se3(random_tangents(18, n=1)[0])
    for xi in random_tangents(19, n=8, angles=(0.0, 0.6), translation=0.3):
        step = expm_se3(xi)
        seq = [start]
        for _ in range(3):
            seq.append(step @ seq[-1] if frame == "left" else seq[-1] @ step)
        seq = [jnp.asarray(t, jnp.float32) for t in seq]
        predicted = np.asarray(constant_velocity(seq[1], seq[2]), np.float64)
        np.testing.assert_allclose(predicted, np.asarray(seq[3], np.float64), atol=5e-5)


def test_constant_velocity_of_a_repeated_pose_is_that_pose():
    pose = jnp.asarray(expm_se3(random_tangents(20, n=1)[0]), jnp.float32)
    np.testing.assert_allclose(np.asarray(constant_velocity(pose, pose)), np.asarray(pose), atol=1e-5)


def test_camera_center_maps_to_the_camera_origin():
    for delta in random_tangents(21, n=8):
        w2c = expm_se3(delta)
        centre = np.asarray(camera_center(jnp.asarray(w2c, jnp.float32)), np.float64)
        np.testing.assert_allclose(w2c[:3, :3] @ centre + w2c[:3, 3], 0.0, atol=1e-5)
        np.testing.assert_allclose(centre, np.linalg.inv(w2c)[:3, 3], atol=1e-5)


def test_rigidity_error_is_zero_for_rigid_and_large_for_non_rigid_matrices():
    transforms = v_se3_exp(jnp.asarray(random_tangents(22), jnp.float32))
    assert float(jnp.max(jax.vmap(rigidity_error)(transforms))) < 2e-6
    rigid = np.asarray(transforms[0], np.float64)
    scaled = rigid.copy()
    scaled[:3, :3] *= 1.01
    sheared = rigid.copy()
    sheared[0, 1] += 0.05
    reflected = rigid @ np.diag([1.0, 1.0, -1.0, 1.0])
    bad_row = rigid.copy()
    bad_row[3] = [0.0, 0.1, 0.0, 1.0]
    for bad, least in ((scaled, 0.02), (sheared, 0.01), (reflected, 1.9), (bad_row, 0.09)):
        assert float(rigidity_error(jnp.asarray(bad, jnp.float32))) > least


def test_downscaled_intrinsics_project_to_the_same_physical_location():
    intr = make_intrinsics(525.0, 520.0, 319.3, 241.7, 481, 641)
    rng = np.random.default_rng(23)
    points = jnp.asarray(np.concatenate([rng.uniform(-1, 1, (32, 2)), rng.uniform(0.5, 4, (32, 1))], 1), jnp.float32)
    uv = np.asarray(project_points(points, intr), np.float64)
    for factor in (1, 2, 3, 4):
        small = intr.downscaled(factor)
        assert (small.height, small.width) == (481 // factor, 641 // factor)
        uv_small = np.asarray(project_points(points, small), np.float64)
        np.testing.assert_allclose(uv_small, (uv + 0.5) / factor - 0.5, rtol=1e-5, atol=1e-3)
    # a 2x2 block's centre: input pixels (2j, 2j+1) average to output pixel j
    small = intr.downscaled(2)
    fx, fy, cx, cy = (float(v) for v in (intr.fx, intr.fy, intr.cx, intr.cy))
    centre_of_block = jnp.asarray([[(0.5 - cx) / fx, (0.5 - cy) / fy, 1.0]])
    np.testing.assert_allclose(np.asarray(project_points(centre_of_block, small)), [[0.0, 0.0]], atol=1e-4)
    for bad in (0, -1, 1.5):
        with pytest.raises(ValueError, match="factor"):
            intr.downscaled(bad)


def test_backproject_inverts_project_points_at_pixel_centres():
    intr = make_intrinsics(40.0, 38.0, 19.3, 15.6, 32, 40)
    depth = jnp.asarray(np.random.default_rng(24).uniform(0.3, 5.0, (32, 40)), jnp.float32)
    points = backproject(depth, intr)
    assert points.shape == (32, 40, 3)
    np.testing.assert_array_equal(np.asarray(points[..., 2]), np.asarray(depth))
    uv = np.asarray(project_points(points, intr))
    rows, cols = np.meshgrid(np.arange(32), np.arange(40), indexing="ij")
    np.testing.assert_allclose(uv[..., 0], cols, atol=1e-4)  # u = column j
    np.testing.assert_allclose(uv[..., 1], rows, atol=1e-4)  # v = row i
    # the principal point is where the optical axis meets the image (no half-pixel offset)
    on_axis = project_points(jnp.asarray([0.0, 0.0, 2.0]), intr)
    np.testing.assert_allclose(np.asarray(on_axis), [19.3, 15.6], atol=1e-6)


def test_calibration_matrix_and_half_fov_follow_the_intrinsics():
    intr = make_intrinsics(40.0, 38.0, 19.3, 15.6, 32, 44)
    k = np.asarray(intr.matrix(), np.float64)
    np.testing.assert_allclose(k, [[40.0, 0, 19.3], [0, 38.0, 15.6], [0, 0, 1]], rtol=1e-6)
    point = np.array([0.3, -0.2, 1.7])
    projected = np.asarray(project_points(jnp.asarray(point), intr))
    np.testing.assert_allclose((k @ point)[:2] / point[2], projected, atol=1e-5)
    tan_x, tan_y = intr.tan_half_fov()
    np.testing.assert_allclose([float(tan_x), float(tan_y)], [44 / 80.0, 32 / 76.0], rtol=1e-6)
    assert intr.shape == (32, 44)


def test_intrinsics_is_a_pytree_with_static_image_size():
    intr = make_intrinsics(40.0, 38.0, 19.3, 15.6, 32, 44)
    leaves, treedef = jax.tree_util.tree_flatten(intr)
    assert len(leaves) == 4  # fx, fy, cx, cy traced; height, width static
    assert isinstance(jax.tree_util.tree_unflatten(treedef, leaves), Intrinsics)

    @jax.jit
    def shape_under_jit(i):
        return jnp.zeros(i.shape).sum() + i.fx

    assert float(shape_under_jit(intr)) == 40.0


def test_the_numpy_float64_twins_give_the_jnp_functions_values():
    """One home, two array types: the host-side quaternion conversions (float64) agree with the traced ones
    (float32, batched) on random rotations and on 180-degree turns (every Shepperd branch), round trip to 1e-14,
    and keep w >= 0."""
    rng = np.random.default_rng(2)
    q = rng.standard_normal((200, 4))
    q[:4] = [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [1e-9, 0.6, 0.8, 0]]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rot = quaternion_to_rotation_np(q)
    np.testing.assert_allclose(rot, np.asarray(quaternion_to_rotation(jnp.asarray(q, jnp.float32))), atol=1e-6)
    np.testing.assert_allclose(rotation_to_quaternion_np(rot),
                               np.asarray(rotation_to_quaternion(jnp.asarray(rot, jnp.float32))), atol=1e-6)
    back = rotation_to_quaternion_np(rot)
    np.testing.assert_allclose(quaternion_to_rotation_np(back), rot, atol=1e-14)
    assert np.all(back[:, 0] >= 0)


def test_the_jnp_and_numpy_twins_take_the_same_batches_and_agree():
    """Each jnp function and its numpy float64 twin (``_np``) take [..., ] batches alike (here [2, 3, ...], angles
    from 0 to near pi) and agree to float32; the batched jnp result is the per-element one."""
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(2, 3, 3))
    angles = np.array([[0.0, 1e-4, 0.5], [1.5, 3.0, np.pi - 1e-3]])
    phi = axes / np.linalg.norm(axes, axis=-1, keepdims=True) * angles[..., None]
    rotations = np.asarray(v_so3_exp(jnp.asarray(phi.reshape(-1, 3), jnp.float32))).reshape(2, 3, 3, 3)
    transforms = np.tile(np.eye(4, dtype=np.float32), (2, 3, 1, 1))
    transforms[..., :3, :3], transforms[..., :3, 3] = rotations, rng.normal(size=(2, 3, 3))
    pairs = [(rotation_angle, rotation_angle_np, rotations), (se3_inverse, se3_inverse_np, transforms),
             (rotation_to_quaternion, rotation_to_quaternion_np, rotations)]
    for jnp_twin, np_twin, batch in pairs:
        got, want = np.asarray(jnp_twin(jnp.asarray(batch))), np_twin(batch)
        assert got.shape == want.shape and got.shape[:2] == (2, 3)
        np.testing.assert_allclose(got, want, atol=2e-5, err_msg=jnp_twin.__name__)
        one = np.asarray(jnp_twin(jnp.asarray(batch[1, 2])))
        np.testing.assert_array_equal(got[1, 2], one, err_msg=jnp_twin.__name__)
    quats = rotation_to_quaternion_np(rotations)
    np.testing.assert_allclose(np.asarray(quaternion_to_rotation(jnp.asarray(quats, jnp.float32))),
                               quaternion_to_rotation_np(quats), atol=2e-6)
    np.testing.assert_allclose(np.asarray(so3_log(jnp.asarray(rotations))), phi, atol=5e-4)
