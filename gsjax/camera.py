"""Pinhole intrinsics and SE(3) pose helpers: the one home of gsjax's pose and rotation conventions, in jnp (traced)
and, at the end, the same formulas in numpy float64 for the host side (trajectory files, evaluation, the viewer).

Conventions (fixed once for all of gsjax, DESIGN 2.2.1):

* Poses are **world-to-camera** 4x4 matrices ``w2c`` (metres). A world point ``x`` maps to the camera frame as
  ``R x + t``; the camera looks down +z, x right, y down (OpenCV).
* Pixel (row i, column j) is sampled at image coordinates (u, v) = (j, i): pixel centres at integers. A camera
  point (X, Y, Z) projects to ``u = fx X/Z + cx``, ``v = fy Y/Z + cy``; :func:`backproject` is its exact inverse.
* Tangent vectors ``delta = (rho, phi)`` in R^6: translation part first, rotation (axis-angle, rad) second.
  Updates are **left perturbations**: ``T = exp(delta) @ T0``.

The exponential and logarithm follow Barfoot, *State Estimation for Robotics*, sections 7.1.3 and 7.1.5; small
angles use Taylor series (with the double-``where`` trick so that gradients stay finite at zero).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.config.fields import check_fields, required

# Below this squared rotation angle (rad^2) the closed forms lose float32 precision; use Taylor series instead.
_SMALL_ANGLE_SQ = 0.04


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels. ``height`` and ``width`` are static ints (they set array shapes).

    Attributes:
      fx: focal length along x (px), a float32 scalar array or a float.
      fy: focal length along y (px), a float32 scalar array or a float.
      cx: principal point's column (px), pixel centres at integers.
      cy: principal point's row (px), pixel centres at integers.
      height: image height (px), a static int.
      width: image width (px), a static int.
    """

    fx: jax.Array | float = required("px", low=0.0, low_open=True, scaling=None)
    fy: jax.Array | float = required("px", low=0.0, low_open=True, scaling=None)
    cx: jax.Array | float = required("px", scaling=None)
    cy: jax.Array | float = required("px", scaling=None)
    height: int = required("px", static=True, low=1)
    width: int = required("px", static=True, low=1)

    def check(self) -> None:
        """Check that this is a valid camera: the image size always (it is static), values only when concrete.

        Raises:
          ValueError: naming the first field that is not valid (e.g. not a scalar, a focal length <= 0, a
            non-integer or non-positive size).
        """
        for name in ("fx", "fy", "cx", "cy"):
            if np.ndim(getattr(self, name)) != 0:
                raise ValueError(f"intrinsics.{name} must be a scalar, got shape {list(np.shape(getattr(self, name)))}")
        check_fields(self, "intrinsics")

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the image (px)."""
        return (self.height, self.width)

    def matrix(self) -> jax.Array:
        """The calibration matrix K.

        Returns:
          [3, 3] float32 ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (px).
        """
        zero, one = jnp.zeros_like(jnp.asarray(self.fx, jnp.float32)), jnp.ones_like(jnp.asarray(self.fx, jnp.float32))
        return jnp.stack(
            [
                jnp.stack([jnp.asarray(self.fx, jnp.float32), zero, jnp.asarray(self.cx, jnp.float32)]),
                jnp.stack([zero, jnp.asarray(self.fy, jnp.float32), jnp.asarray(self.cy, jnp.float32)]),
                jnp.stack([zero, zero, one]),
            ]
        )

    def tan_half_fov(self) -> tuple[jax.Array, jax.Array]:
        """Tangents of the half fields of view, as in 3DGS.

        Returns:
          ``(tan(fov_x / 2), tan(fov_y / 2)) = (W / (2 fx), H / (2 fy))``, scalar arrays.
        """
        return self.width / (2.0 * jnp.asarray(self.fx)), self.height / (2.0 * jnp.asarray(self.fy))

    def downscaled(self, factor: int) -> "Intrinsics":
        """Intrinsics of the image reduced by an integer factor (each output pixel = a factor x factor block).

        With pixel centres at integers, output pixel j covers input pixels ``f j .. f j + f - 1`` whose centre is
        ``f j + (f - 1) / 2``, hence ``fx' = fx / f`` and ``cx' = (cx + 0.5) / f - 0.5``.

        Args:
          factor: the reduction f, a positive int.

        Returns:
          The reduced camera; its height and width are floored (``height // f``, ``width // f``).

        Raises:
          ValueError: ``factor`` is not a positive int, or leaves no pixel.
        """
        if not isinstance(factor, int) or factor < 1:
            raise ValueError(f"downscale factor must be a positive int, got {factor!r}")
        if factor > min(self.height, self.width):
            raise ValueError(f"downscale factor {factor} leaves no pixel of a {self.width}x{self.height} image")
        f = float(factor)
        return Intrinsics(
            fx=self.fx / f,
            fy=self.fy / f,
            cx=(self.cx + 0.5) / f - 0.5,
            cy=(self.cy + 0.5) / f - 0.5,
            height=self.height // factor,
            width=self.width // factor,
        )

    def strided(self, row: int | jax.Array, col: int | jax.Array) -> "Intrinsics":
        """Intrinsics of every other pixel: output pixel (i, j) is input pixel (2 i + ``row``, 2 j + ``col``).

        So ``fx' = fx / 2``, ``cx' = (cx - col) / 2``. Rendered with the dilation divided by 4 (the 2D covariance
        shrinks by 4 in these pixels), the render is the input render's pixels there.

        Args:
          row: row offset, 0 or 1 (may be traced).
          col: column offset, 0 or 1 (may be traced).

        Returns:
          The strided camera, ``height // 2`` x ``width // 2``.
        """
        return Intrinsics(
            fx=self.fx / 2.0,
            fy=self.fy / 2.0,
            cx=(self.cx - col) / 2.0,
            cy=(self.cy - row) / 2.0,
            height=self.height // 2,
            width=self.width // 2,
        )


def make_intrinsics(fx: float, fy: float, cx: float, cy: float, height: int, width: int) -> Intrinsics:
    """Intrinsics with float32 scalar arrays, after checking the values.

    Args:
      fx: focal length along x (px), > 0.
      fy: focal length along y (px), > 0.
      cx: principal point's column (px), pixel centres at integers.
      cy: principal point's row (px).
      height: image height (px); a whole number given as a float (480.0) is accepted.
      width: image width (px), likewise.

    Returns:
      The camera, ``fx .. cy`` float32 scalar arrays, ``height`` and ``width`` ints.

    Raises:
      ValueError: naming the first value that is not valid.
    """
    def whole(value):
        return int(value) if isinstance(value, (float, np.floating)) and float(value).is_integer() else value

    Intrinsics(fx, fy, cx, cy, whole(height), whole(width)).check()
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return Intrinsics(f32(fx), f32(fy), f32(cx), f32(cy), int(height), int(width))


def project_points(points_cam: jax.Array, intrinsics: Intrinsics) -> jax.Array:
    """Project camera-frame points to pixel coordinates, ``u = fx X/Z + cx``, ``v = fy Y/Z + cy``.

    Args:
      points_cam: [..., 3] points (X, Y, Z) in the camera frame (m), Z > 0 (not checked).
      intrinsics: the camera.

    Returns:
      [..., 2] pixel coordinates (u, v) = (column, row) (px).
    """
    x, y, z = points_cam[..., 0], points_cam[..., 1], points_cam[..., 2]
    return jnp.stack([intrinsics.fx * x / z + intrinsics.cx, intrinsics.fy * y / z + intrinsics.cy], axis=-1)


def backproject(depth: jax.Array, intrinsics: Intrinsics) -> jax.Array:
    """Back-project a depth image to camera-frame points: the inverse of :func:`project_points`.

    Args:
      depth: [H, W] depth along the optical axis (m), float.
      intrinsics: the camera (``fx .. cy`` are used; H and W come from ``depth``).

    Returns:
      [H, W, 3] points (X, Y, Z = depth) in the camera frame (m), dtype of ``depth``; pixel (i, j) at its centre
        (u, v) = (j, i).
    """
    height, width = depth.shape
    v, u = jnp.meshgrid(jnp.arange(height, dtype=depth.dtype), jnp.arange(width, dtype=depth.dtype), indexing="ij")
    x = (u - intrinsics.cx) / intrinsics.fx * depth
    y = (v - intrinsics.cy) / intrinsics.fy * depth
    return jnp.stack([x, y, depth], axis=-1)


# ----------------------------------------------------------------------------------------------- SO(3) / SE(3)


def hat(phi: jax.Array) -> jax.Array:
    """Skew-symmetric matrix of a 3-vector, so that ``hat(a) @ b = cross(a, b)``.

    Args:
      phi: [..., 3] vectors.

    Returns:
      [..., 3, 3] matrices, dtype of ``phi``.
    """
    x, y, z = phi[..., 0], phi[..., 1], phi[..., 2]
    zero = jnp.zeros_like(x)
    return jnp.stack(
        [jnp.stack([zero, -z, y], -1), jnp.stack([z, zero, -x], -1), jnp.stack([-y, x, zero], -1)], axis=-2
    )


def _rotation_coefficients(phi: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3 for t = |phi|, stable at t -> 0."""
    theta_sq = jnp.sum(phi * phi, axis=-1)
    small = theta_sq < _SMALL_ANGLE_SQ
    safe_sq = jnp.where(small, 1.0, theta_sq)  # keeps the unused branch (and its gradient) finite
    theta = jnp.sqrt(safe_sq)
    half_sin = jnp.sin(0.5 * theta)
    a = jnp.where(small, 1.0 - theta_sq / 6.0 + theta_sq**2 / 120.0, jnp.sin(theta) / theta)
    b = jnp.where(small, 0.5 - theta_sq / 24.0 + theta_sq**2 / 720.0, 2.0 * half_sin * half_sin / safe_sq)
    c = jnp.where(
        small,
        1.0 / 6.0 - theta_sq / 120.0 + theta_sq**2 / 5040.0 - theta_sq**3 / 362880.0,
        (theta - jnp.sin(theta)) / (safe_sq * theta),
    )
    return a, b, c


def so3_exp(phi: jax.Array) -> jax.Array:
    """Rotation matrix of an axis-angle vector (Rodrigues; Taylor series near 0, finite gradients there).

    Args:
      phi: [..., 3] axis-angle: unit axis times angle (rad).

    Returns:
      [..., 3, 3] rotation matrices, dtype of ``phi``.
    """
    a, b, _ = _rotation_coefficients(phi)
    k = hat(phi)
    return jnp.eye(3, dtype=phi.dtype) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def rotation_to_quaternion(rotation: jax.Array) -> jax.Array:
    """Unit quaternions of rotation matrices (Shepperd's method).

    Args:
      rotation: [..., 3, 3] rotation matrices.

    Returns:
      [..., 4] unit quaternions, scalar first (w, x, y, z), with w >= 0.
    """
    return _shepperd(rotation, jnp)


def quaternion_to_rotation(quat: jax.Array) -> jax.Array:
    """Rotation matrices of quaternions.

    Args:
      quat: [..., 4] quaternions, scalar first (w, x, y, z); normalised here (any non-zero norm).

    Returns:
      [..., 3, 3] rotation matrices.
    """
    return _quaternion_matrix(quat / jnp.linalg.norm(quat, axis=-1, keepdims=True), jnp)


def so3_log(rotation: jax.Array) -> jax.Array:
    """Axis-angle vectors of rotation matrices, the inverse of :func:`so3_exp`; robust near 0 and pi (quaternions).

    Args:
      rotation: [..., 3, 3] rotation matrices.

    Returns:
      [..., 3] axis-angle (rad), angle in [0, pi].
    """
    q = rotation_to_quaternion(rotation)
    w, v = q[..., 0], q[..., 1:]
    vnorm_sq = jnp.sum(v * v, axis=-1)
    small = vnorm_sq < 1e-12
    vnorm = jnp.sqrt(jnp.where(small, 1.0, vnorm_sq))
    # angle = 2 atan2(|v|, w); phi = angle * v / |v|, and -> 2 v / w as |v| -> 0.
    scale = jnp.where(small, 2.0 / w, 2.0 * jnp.arctan2(vnorm, w) / vnorm)
    return scale[..., None] * v


def rotation_angle(rotation: jax.Array) -> jax.Array:
    """Rotation angles of rotation matrices (:func:`rotation_angle_np` in numpy float64).

    Args:
      rotation: [..., 3, 3] rotation matrices.

    Returns:
      [...] angles (rad), in [0, pi].
    """
    return jnp.linalg.norm(so3_log(rotation), axis=-1)


def se3_exp(delta: jax.Array) -> jax.Array:
    """Exponential map of SE(3): the rigid transform ``[[R, V rho], [0, 1]]`` of a tangent vector.

    Args:
      delta: [6] tangent vector (rho, phi): translation part (m) first, rotation (axis-angle, rad) second.

    Returns:
      [4, 4] rigid transform, dtype of ``delta``.
    """
    rho, phi = delta[:3], delta[3:]
    a, b, c = _rotation_coefficients(phi)
    k = hat(phi)
    k2 = k @ k
    eye = jnp.eye(3, dtype=delta.dtype)
    rot = eye + a * k + b * k2
    v = eye + b * k + c * k2
    return from_rotation_translation(rot, v @ rho)


def se3_log(transform: jax.Array) -> jax.Array:
    """Logarithm of SE(3), the inverse of :func:`se3_exp`.

    Args:
      transform: [4, 4] rigid transform (m).

    Returns:
      [6] tangent vector (rho, phi): translation part (m), then axis-angle (rad, angle in [0, pi]).
    """
    phi = so3_log(transform[:3, :3])
    _, b, c = _rotation_coefficients(phi)
    k = hat(phi)
    v = jnp.eye(3, dtype=transform.dtype) + b * k + c * (k @ k)
    rho = jnp.linalg.solve(v, transform[:3, 3])
    return jnp.concatenate([rho, phi])


def from_rotation_translation(rotation: jax.Array, translation: jax.Array) -> jax.Array:
    """Homogeneous transforms ``[[R, t], [0, 1]]``.

    Args:
      rotation: [..., 3, 3] rotations R.
      translation: [..., 3] translations t (m).

    Returns:
      [..., 4, 4] transforms.
    """
    top = jnp.concatenate([rotation, translation[..., :, None]], axis=-1)
    bottom = jnp.broadcast_to(jnp.array([0.0, 0.0, 0.0, 1.0], dtype=top.dtype), (*top.shape[:-2], 1, 4))
    return jnp.concatenate([top, bottom], axis=-2)


def se3_inverse(transform: jax.Array) -> jax.Array:
    """Inverses of rigid transforms, ``[[R^T, -R^T t], [0, 1]]`` (exact for rigid inputs; :func:`se3_inverse_np` in
    numpy float64).

    Args:
      transform: [..., 4, 4] rigid transforms.

    Returns:
      [..., 4, 4] their inverses (a w2c for a c2w and vice versa).
    """
    rot_t = jnp.swapaxes(transform[..., :3, :3], -1, -2)
    return from_rotation_translation(rot_t, -(rot_t @ transform[..., :3, 3, None])[..., 0])


def perturb_left(delta: jax.Array, transform: jax.Array) -> jax.Array:
    """Left perturbation ``exp(delta) @ transform`` (the update rule of tracking).

    Args:
      delta: [6] tangent vector (rho in m, phi in rad), as :func:`se3_exp`.
      transform: [4, 4] rigid transform (a w2c pose in tracking).

    Returns:
      [4, 4] the perturbed transform.
    """
    return se3_exp(delta) @ transform


def orthonormalize(transform: jax.Array) -> jax.Array:
    """The nearest rigid transform, in practice: rotation re-built from its (normalised) quaternion, last row
    reset. Repeated float32 products drift off SE(3); poses carried from frame to frame are passed through this.

    Args:
      transform: [4, 4] nearly rigid transform.

    Returns:
      [4, 4] rigid transform with the same translation.
    """
    rotation = quaternion_to_rotation(rotation_to_quaternion(transform[:3, :3]))
    return from_rotation_translation(rotation, transform[:3, 3])


def camera_center(w2c: jax.Array) -> jax.Array:
    """Camera centre of a world-to-camera pose, ``-R^T t``.

    Args:
      w2c: [4, 4] world-to-camera pose (m).

    Returns:
      [3] camera centre in world coordinates (m).
    """
    return -w2c[:3, :3].T @ w2c[:3, 3]


def constant_velocity(w2c_prev2: jax.Array, w2c_prev1: jax.Array) -> jax.Array:
    """Constant-velocity prediction on SE(3): apply the last relative motion once more.

    ``T_t = (T_{t-1} T_{t-2}^{-1}) T_{t-1}``; in camera-to-world terms this is ``C_{t-1} (C_{t-2}^{-1} C_{t-1})``,
    i.e. the body-frame motion of the last step repeated.

    Args:
      w2c_prev2: [4, 4] world-to-camera pose two frames back.
      w2c_prev1: [4, 4] world-to-camera pose of the previous frame.

    Returns:
      [4, 4] predicted world-to-camera pose of the current frame.
    """
    return w2c_prev1 @ se3_inverse(w2c_prev2) @ w2c_prev1


def rigidity_error(transform: jax.Array | np.ndarray) -> jax.Array | np.ndarray:
    """How far matrices are from rigid transforms: max of |R^T R - I|, |det R - 1| and |last row - e4|.

    Used by the renderer on w2c and by the dataset readers on GT poses.

    Args:
      transform: [..., 4, 4] matrices; a numpy input is checked in numpy (host side: safe while a jit traces).

    Returns:
      [...] errors (0 for a rigid transform), numpy for a numpy input, else a jax array.
    """
    xp = np if isinstance(transform, np.ndarray) else jnp
    rot = transform[..., :3, :3]
    ortho = xp.max(xp.abs(xp.swapaxes(rot, -1, -2) @ rot - xp.eye(3, dtype=transform.dtype)), axis=(-1, -2))
    det = xp.abs(xp.linalg.det(rot) - 1.0)
    last = xp.max(xp.abs(transform[..., 3, :] - xp.array([0.0, 0.0, 0.0, 1.0], dtype=transform.dtype)), axis=-1)
    return xp.maximum(xp.maximum(ortho, det), last)


# --------------------------------------------------- the same conventions in numpy float64 (host side: files, eval)


def rotation_to_quaternion_np(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternions of rotation matrices in numpy float64: the formula of :func:`rotation_to_quaternion`.

    Args:
      rotation: [..., 3, 3] rotation matrices.

    Returns:
      [..., 4] float64 unit quaternions, scalar first (w, x, y, z), with w >= 0.
    """
    return _shepperd(np.asarray(rotation, np.float64), np)


def quaternion_to_rotation_np(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions in numpy float64: :func:`quaternion_to_rotation` without its
    normalisation (the readers normalise what they read).

    Args:
      quat: [..., 4] unit quaternions, scalar first (w, x, y, z).

    Returns:
      [..., 3, 3] float64 rotation matrices.
    """
    return _quaternion_matrix(np.asarray(quat, np.float64), np)


def se3_inverse_np(transform: np.ndarray) -> np.ndarray:
    """Inverses of rigid transforms via ``R^T`` in numpy float64: :func:`se3_inverse`'s formula.

    Args:
      transform: [..., 4, 4] rigid transforms.

    Returns:
      [..., 4, 4] float64 inverses, last row exactly (0, 0, 0, 1).
    """
    transform = np.asarray(transform, np.float64)
    rot_t = np.swapaxes(transform[..., :3, :3], -1, -2)
    out = np.zeros_like(transform)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -(rot_t @ transform[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def invert_transform(transform: np.ndarray) -> np.ndarray:
    """Exact inverse of invertible transforms in numpy float64, for poses rigid only to rounding (a float32 pose
    from the core, a ground-truth matrix read from a file): files written from a pose (``trajectory.txt``) keep the
    digits of its exact inverse. :func:`se3_inverse_np` (``R^T``) inverts the nearest rigid transform, equal to this
    to within the pose's own orthonormality error (about 1e-7 for float32).

    Args:
      transform: [..., 4, 4] invertible transforms.

    Returns:
      [..., 4, 4] float64 inverses.
    """
    return np.linalg.inv(np.asarray(transform, np.float64))


def rotation_angle_np(rotation: np.ndarray) -> np.ndarray:
    """Rotation angle of rotation matrices in numpy float64; accurate at small angles (atan2 of the sine from the
    skew part and the cosine from the trace).

    Args:
      rotation: [..., 3, 3] rotation matrices.

    Returns:
      [...] float64 angles (rad), in [0, pi].
    """
    r = np.asarray(rotation, np.float64)
    cos = 0.5 * (r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2] - 1.0)
    skew = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    return np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), cos)


def _quaternion_matrix(quat, xp):
    """Unit quaternions [..., 4] (w, x, y, z) -> rotation matrices [..., 3, 3] (``xp``: jnp or numpy)."""
    w, x, y, z = (quat[..., i] for i in range(4))
    return xp.stack(
        [
            xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            xp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            xp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def _shepperd(r, xp):
    """Rotation matrices [..., 3, 3] -> unit quaternions [..., 4] (w, x, y, z), w >= 0 (``xp``: jnp or numpy)."""
    trace = r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2]
    candidates = xp.stack(
        [
            xp.stack([1.0 + trace, r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                      r[..., 1, 0] - r[..., 0, 1]], -1),
            xp.stack([r[..., 2, 1] - r[..., 1, 2], 1.0 + r[..., 0, 0] - r[..., 1, 1] - r[..., 2, 2],
                      r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0]], -1),
            xp.stack([r[..., 0, 2] - r[..., 2, 0], r[..., 0, 1] + r[..., 1, 0],
                      1.0 - r[..., 0, 0] + r[..., 1, 1] - r[..., 2, 2], r[..., 1, 2] + r[..., 2, 1]], -1),
            xp.stack([r[..., 1, 0] - r[..., 0, 1], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1],
                      1.0 - r[..., 0, 0] - r[..., 1, 1] + r[..., 2, 2]], -1),
        ],
        -2,
    )  # [..., 4 candidates, 4]; each is well conditioned when its pivot is the largest
    pivot = xp.argmax(xp.stack([trace, r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]], -1), axis=-1)
    q = xp.take_along_axis(candidates, pivot[..., None, None], axis=-2)[..., 0, :]
    q = q / xp.linalg.norm(q, axis=-1, keepdims=True)
    return xp.where(q[..., :1] < 0, -q, q)
