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

from gsjax.config_fields import check_fields, required

# Below this squared rotation angle (rad^2) the closed forms lose float32 precision; use Taylor series instead.
_SMALL_ANGLE_SQ = 0.04


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels. ``height`` and ``width`` are static ints (they set array shapes).

    Attributes:
      fx, fy: focal lengths (px), scalar arrays or floats.
      cx, cy: principal point (px) in the integer-pixel-centre convention.
      height, width: image size (px).
    """

    fx: jax.Array | float = required("px", low=0.0, low_open=True, scaling=None)
    fy: jax.Array | float = required("px", low=0.0, low_open=True, scaling=None)
    cx: jax.Array | float = required("px", scaling=None)
    cy: jax.Array | float = required("px", scaling=None)
    height: int = required("px", static=True, low=1)
    width: int = required("px", static=True, low=1)

    def check(self) -> None:
        """ValueError naming the first field that is not a valid camera (values are checked when concrete: not
        under a trace; the image size always, it is static)."""
        for name in ("fx", "fy", "cx", "cy"):
            if np.ndim(getattr(self, name)) != 0:
                raise ValueError(f"intrinsics.{name} must be a scalar, got shape {list(np.shape(getattr(self, name)))}")
        check_fields(self, "intrinsics")

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def matrix(self) -> jax.Array:
        """The 3x3 calibration matrix K."""
        zero, one = jnp.zeros_like(jnp.asarray(self.fx, jnp.float32)), jnp.ones_like(jnp.asarray(self.fx, jnp.float32))
        return jnp.stack(
            [
                jnp.stack([jnp.asarray(self.fx, jnp.float32), zero, jnp.asarray(self.cx, jnp.float32)]),
                jnp.stack([zero, jnp.asarray(self.fy, jnp.float32), jnp.asarray(self.cy, jnp.float32)]),
                jnp.stack([zero, zero, one]),
            ]
        )

    def tan_half_fov(self) -> tuple[jax.Array, jax.Array]:
        """(tan(fov_x / 2), tan(fov_y / 2)) = (W / (2 fx), H / (2 fy)), as in 3DGS."""
        return self.width / (2.0 * jnp.asarray(self.fx)), self.height / (2.0 * jnp.asarray(self.fy))

    def downscaled(self, factor: int) -> "Intrinsics":
        """Intrinsics of the image reduced by an integer ``factor`` (each output pixel = a factor x factor block).

        With pixel centres at integers, output pixel j covers input pixels ``f j .. f j + f - 1`` whose centre is
        ``f j + (f - 1) / 2``, hence ``fx' = fx / f`` and ``cx' = (cx + 0.5) / f - 0.5``. Sizes are floored.
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
        """Intrinsics of every other pixel of this image: output pixel (i, j) is input pixel (2 i + ``row``, 2 j +
        ``col``) (offsets 0 or 1, may be traced), so ``fx' = fx / 2``, ``cx' = (cx - col) / 2``; sizes floored.
        Rendered with the dilation divided by 4 (the 2D covariance shrinks by 4 in these pixels), the render is the
        input render's pixels there."""
        return Intrinsics(
            fx=self.fx / 2.0,
            fy=self.fy / 2.0,
            cx=(self.cx - col) / 2.0,
            cy=(self.cy - row) / 2.0,
            height=self.height // 2,
            width=self.width // 2,
        )


def make_intrinsics(fx: float, fy: float, cx: float, cy: float, height: int, width: int) -> Intrinsics:
    """Intrinsics with float32 scalar arrays, after checking the values (ValueError naming the bad one); a whole
    number given as a float (640.0) is a valid size."""
    def whole(value):
        return int(value) if isinstance(value, (float, np.floating)) and float(value).is_integer() else value

    Intrinsics(fx, fy, cx, cy, whole(height), whole(width)).check()
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return Intrinsics(f32(fx), f32(fy), f32(cx), f32(cy), int(height), int(width))


def project_points(points_cam: jax.Array, intrinsics: Intrinsics) -> jax.Array:
    """Camera-frame points [..., 3] (m) -> pixel coordinates [..., 2] (u, v) in px."""
    x, y, z = points_cam[..., 0], points_cam[..., 1], points_cam[..., 2]
    return jnp.stack([intrinsics.fx * x / z + intrinsics.cx, intrinsics.fy * y / z + intrinsics.cy], axis=-1)


def backproject(depth: jax.Array, intrinsics: Intrinsics) -> jax.Array:
    """Depth image [H, W] (m, along the optical axis) -> camera-frame points [H, W, 3] (m).

    Exact inverse of :func:`project_points` at the pixel centres (u, v) = (column, row).
    """
    height, width = depth.shape
    v, u = jnp.meshgrid(jnp.arange(height, dtype=depth.dtype), jnp.arange(width, dtype=depth.dtype), indexing="ij")
    x = (u - intrinsics.cx) / intrinsics.fx * depth
    y = (v - intrinsics.cy) / intrinsics.fy * depth
    return jnp.stack([x, y, depth], axis=-1)


# ----------------------------------------------------------------------------------------------- SO(3) / SE(3)


def hat(phi: jax.Array) -> jax.Array:
    """Skew-symmetric matrix [3, 3] of a 3-vector, so that ``hat(a) @ b = cross(a, b)``."""
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
    """Axis-angle [3] (rad) -> rotation matrix [3, 3] (Rodrigues)."""
    a, b, _ = _rotation_coefficients(phi)
    k = hat(phi)
    return jnp.eye(3, dtype=phi.dtype) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def rotation_to_quaternion(rotation: jax.Array) -> jax.Array:
    """Rotation matrices [..., 3, 3] -> unit quaternions [..., 4] (w, x, y, z) with w >= 0 (Shepperd's method)."""
    return _shepperd(rotation, jnp)


def quaternion_to_rotation(quat: jax.Array) -> jax.Array:
    """Quaternions [..., 4] (w, x, y, z), normalised here, -> rotation matrices [..., 3, 3]."""
    return _quaternion_matrix(quat / jnp.linalg.norm(quat, axis=-1, keepdims=True), jnp)


def so3_log(rotation: jax.Array) -> jax.Array:
    """Rotation matrix [3, 3] -> axis-angle [3] (rad), angle in [0, pi]; robust near 0 and pi (via quaternions)."""
    q = rotation_to_quaternion(rotation)
    w, v = q[0], q[1:]
    vnorm_sq = jnp.sum(v * v)
    small = vnorm_sq < 1e-12
    vnorm = jnp.sqrt(jnp.where(small, 1.0, vnorm_sq))
    # angle = 2 atan2(|v|, w); phi = angle * v / |v|, and -> 2 v / w as |v| -> 0.
    scale = jnp.where(small, 2.0 / w, 2.0 * jnp.arctan2(vnorm, w) / vnorm)
    return scale * v


def rotation_angle(rotation: jax.Array) -> jax.Array:
    """Rotation angle (rad, in [0, pi]) of a rotation matrix."""
    return jnp.linalg.norm(so3_log(rotation))


def se3_exp(delta: jax.Array) -> jax.Array:
    """Tangent vector [6] = (rho, phi) -> 4x4 rigid transform [[R, V rho], [0, 1]]."""
    rho, phi = delta[:3], delta[3:]
    a, b, c = _rotation_coefficients(phi)
    k = hat(phi)
    k2 = k @ k
    eye = jnp.eye(3, dtype=delta.dtype)
    rot = eye + a * k + b * k2
    v = eye + b * k + c * k2
    return from_rotation_translation(rot, v @ rho)


def se3_log(transform: jax.Array) -> jax.Array:
    """4x4 rigid transform -> tangent vector [6] = (rho, phi), the inverse of :func:`se3_exp`."""
    phi = so3_log(transform[:3, :3])
    _, b, c = _rotation_coefficients(phi)
    k = hat(phi)
    v = jnp.eye(3, dtype=transform.dtype) + b * k + c * (k @ k)
    rho = jnp.linalg.solve(v, transform[:3, 3])
    return jnp.concatenate([rho, phi])


def from_rotation_translation(rotation: jax.Array, translation: jax.Array) -> jax.Array:
    """[3, 3] rotation and [3] translation -> 4x4 transform."""
    top = jnp.concatenate([rotation, translation[:, None]], axis=1)
    bottom = jnp.array([[0.0, 0.0, 0.0, 1.0]], dtype=top.dtype)
    return jnp.concatenate([top, bottom], axis=0)


def se3_inverse(transform: jax.Array) -> jax.Array:
    """Inverse of a rigid 4x4 transform, using R^T (exact for rigid inputs)."""
    rot_t = transform[:3, :3].T
    return from_rotation_translation(rot_t, -rot_t @ transform[:3, 3])


def perturb_left(delta: jax.Array, transform: jax.Array) -> jax.Array:
    """Left perturbation ``exp(delta) @ transform`` (the update rule of tracking)."""
    return se3_exp(delta) @ transform


def orthonormalize(transform: jax.Array) -> jax.Array:
    """The nearest rigid transform, in practice: rotation re-built from its (normalised) quaternion, last row
    reset. Repeated float32 products drift off SE(3); poses carried from frame to frame are passed through this."""
    rotation = quaternion_to_rotation(rotation_to_quaternion(transform[:3, :3]))
    return from_rotation_translation(rotation, transform[:3, 3])


def camera_center(w2c: jax.Array) -> jax.Array:
    """Camera centre in world coordinates [3] (m) of a world-to-camera pose: ``-R^T t``."""
    return -w2c[:3, :3].T @ w2c[:3, 3]


def constant_velocity(w2c_prev2: jax.Array, w2c_prev1: jax.Array) -> jax.Array:
    """Constant-velocity prediction on SE(3): apply the last relative motion once more.

    ``T_t = (T_{t-1} T_{t-2}^{-1}) T_{t-1}``; in camera-to-world terms this is ``C_{t-1} (C_{t-2}^{-1} C_{t-1})``,
    i.e. the body-frame motion of the last step repeated.
    """
    return w2c_prev1 @ se3_inverse(w2c_prev2) @ w2c_prev1


def rigidity_error(transform: jax.Array | np.ndarray) -> jax.Array | np.ndarray:
    """How far 4x4 matrices [..., 4, 4] are from rigid transforms -> [...]: max of |R^T R - I|, |det R - 1| and
    |last row - e4| (0 for a rigid transform). Used by the renderer on w2c and by the dataset readers on GT poses.

    A numpy input is checked in numpy (host side, no tracing: safe to call while an outer jit is tracing)."""
    xp = np if isinstance(transform, np.ndarray) else jnp
    rot = transform[..., :3, :3]
    ortho = xp.max(xp.abs(xp.swapaxes(rot, -1, -2) @ rot - xp.eye(3, dtype=transform.dtype)), axis=(-1, -2))
    det = xp.abs(xp.linalg.det(rot) - 1.0)
    last = xp.max(xp.abs(transform[..., 3, :] - xp.array([0.0, 0.0, 0.0, 1.0], dtype=transform.dtype)), axis=-1)
    return xp.maximum(xp.maximum(ortho, det), last)


# --------------------------------------------------- the same conventions in numpy float64 (host side: files, eval)


def rotation_to_quaternion_wxyz(rotation: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] -> unit quaternions [..., 4] (w, x, y, z), w >= 0, float64: the formula of
    :func:`rotation_to_quaternion`."""
    return _shepperd(np.asarray(rotation, np.float64), np)


def quaternion_wxyz_to_rotation(quat: np.ndarray) -> np.ndarray:
    """Unit quaternions [..., 4] (w, x, y, z) -> rotation matrices [..., 3, 3], float64: the formula of
    :func:`quaternion_to_rotation`, without its normalisation (the readers normalise what they read)."""
    return _quaternion_matrix(np.asarray(quat, np.float64), np)


def invert_rigid(transform: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms [..., 4, 4] via ``R^T`` (float64): :func:`se3_inverse` batched."""
    transform = np.asarray(transform, np.float64)
    rot_t = np.swapaxes(transform[..., :3, :3], -1, -2)
    out = np.zeros_like(transform)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -(rot_t @ transform[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def invert_transform(transform: np.ndarray) -> np.ndarray:
    """Exact inverse of invertible transforms [..., 4, 4] (float64), for poses that are rigid only to rounding: a
    float32 pose from the core, a ground-truth matrix read from a file. Files written from a pose (``trajectory.txt``)
    keep the digits of its exact inverse; :func:`invert_rigid` (``R^T``) is the inverse of the nearest rigid
    transform, equal to this to within the pose's own orthonormality error (about 1e-7 for float32)."""
    return np.linalg.inv(np.asarray(transform, np.float64))


def rotation_angle_rad(rotation: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, pi]) of rotation matrices [..., 3, 3], float64; accurate at small angles (atan2
    of the sine from the skew part and the cosine from the trace)."""
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
