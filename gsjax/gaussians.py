"""The Gaussian map: a fixed-capacity pytree of isotropic, view-independent 3D Gaussians (SplaTAM's parameters).

Slots with ``active == False`` are free: they render nothing and receive no gradient. Densification writes into
free slots; capacity is a static shape, grown by the caller (never silently).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.config.fields import is_checkable

if TYPE_CHECKING:
    from gsjax.camera import Intrinsics


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gaussians:
    """Isotropic 3D Gaussians, N slots.

    Attributes:
      means: [N, 3] float32, world-frame centres (m).
      log_scales: [N] float32, log of the standard deviation (m); scale = exp(log_scales).
      logit_opacities: [N] float32; opacity = sigmoid(logit_opacities).
      rgb: [N, 3] float32, colours used as stored (not clamped).
      active: [N] bool, which slots hold a Gaussian.
    """

    means: jax.Array
    log_scales: jax.Array
    logit_opacities: jax.Array
    rgb: jax.Array
    active: jax.Array

    @property
    def capacity(self) -> int:
        """N, the number of slots (static)."""
        return self.means.shape[-2]

    @property
    def scales(self) -> jax.Array:
        """[N] standard deviations (m), ``exp(log_scales)``."""
        return jnp.exp(self.log_scales)

    @property
    def opacities(self) -> jax.Array:
        """[N] opacities in (0, 1), ``sigmoid(logit_opacities)``."""
        return jax.nn.sigmoid(self.logit_opacities)

    def num_active(self) -> jax.Array:
        """Number of occupied slots.

        Returns:
          [] int32 (or [...] for a stacked map), the count of ``active``.
        """
        return jnp.sum(self.active.astype(jnp.int32), axis=-1)

    @staticmethod
    def empty(capacity: int) -> "Gaussians":
        """A map with every slot free.

        Args:
          capacity: N, the number of slots.

        Returns:
          Gaussians of N slots, all fields zero (float32) and ``active`` all False.
        """
        return Gaussians(
            means=jnp.zeros((capacity, 3), jnp.float32),
            log_scales=jnp.zeros((capacity,), jnp.float32),
            logit_opacities=jnp.zeros((capacity,), jnp.float32),
            rgb=jnp.zeros((capacity, 3), jnp.float32),
            active=jnp.zeros((capacity,), bool),
        )

    @staticmethod
    def create(
        means: jax.typing.ArrayLike,
        rgb: jax.typing.ArrayLike,
        scales: jax.typing.ArrayLike,
        opacities: jax.typing.ArrayLike = 0.5,
        capacity: int | None = None,
    ) -> "Gaussians":
        """Gaussians from their natural parameters, padded with free slots.

        Args:
          means: [n, 3] world-frame centres (m).
          rgb: [n, 3] colours (in [0, 1] for images in [0, 1]).
          scales: [n] or scalar standard deviations (m), > 0.
          opacities: [n] or scalar opacities in (0, 1).
          capacity: N >= n slots; default n.

        Returns:
          Gaussians of N float32 slots, the first n active (log scales, logit opacities), the rest free.

        Raises:
          ValueError: a shape is wrong, a scale <= 0 or an opacity outside (0, 1) (values checked when concrete),
            or ``capacity`` < n.
        """
        means = jnp.asarray(means, jnp.float32)
        if means.ndim != 2 or means.shape[1] != 3:
            raise ValueError(f"means must have shape [n, 3], got {means.shape}")
        n = means.shape[0]
        rgb = jnp.asarray(rgb, jnp.float32)
        if rgb.shape != (n, 3):
            raise ValueError(f"rgb must have shape [{n}, 3], got {rgb.shape}")
        scales = jnp.broadcast_to(jnp.asarray(scales, jnp.float32), (n,))
        opacities = jnp.broadcast_to(jnp.asarray(opacities, jnp.float32), (n,))
        if is_checkable((scales, opacities)):
            if not bool(jnp.all(scales > 0)):
                raise ValueError("scales must be > 0")
            if not bool(jnp.all((opacities > 0) & (opacities < 1))):
                raise ValueError("opacities must lie in (0, 1)")
        capacity = n if capacity is None else int(capacity)
        if capacity < n:
            raise ValueError(f"capacity {capacity} is smaller than the number of Gaussians {n}")
        pad = capacity - n
        return Gaussians(
            means=jnp.pad(means, ((0, pad), (0, 0))),
            log_scales=jnp.pad(jnp.log(scales), (0, pad)),
            logit_opacities=jnp.pad(jnp.log(opacities) - jnp.log1p(-opacities), (0, pad)),
            rgb=jnp.pad(rgb, ((0, pad), (0, 0))),
            active=jnp.arange(capacity) < n,
        )

    def without_nonfinite(self) -> tuple["Gaussians", jax.Array]:
        """Free every active slot whose parameters are not all finite (reset to an empty slot's zeros, so it
        cannot reach a later sum as NaN).

        Returns:
          gaussians: the cleaned map, same capacity.
          freed: [] int32 number of slots freed.
        """
        finite = (jnp.all(jnp.isfinite(self.means), axis=-1) & jnp.isfinite(self.log_scales)
                  & jnp.isfinite(self.logit_opacities) & jnp.all(jnp.isfinite(self.rgb), axis=-1))
        bad = self.active & ~finite
        clear = lambda x: jnp.where(bad.reshape(bad.shape + (1,) * (x.ndim - bad.ndim)), 0.0, x)  # noqa: E731
        cleaned = Gaussians(means=clear(self.means), log_scales=clear(self.log_scales),
                            logit_opacities=clear(self.logit_opacities), rgb=clear(self.rgb),
                            active=self.active & ~bad)
        return cleaned, jnp.sum(bad.astype(jnp.int32), axis=-1)

    def grow(self, capacity: int) -> "Gaussians":
        """The same map with free slots appended (capacity growth between scan chunks).

        Args:
          capacity: the new number of slots, >= the current one.

        Returns:
          Gaussians of ``capacity`` slots, the existing ones first and unchanged.

        Raises:
          ValueError: ``capacity`` is smaller than the current capacity.
        """
        pad = capacity - self.capacity
        if pad < 0:
            raise ValueError(f"cannot shrink capacity from {self.capacity} to {capacity}")
        return Gaussians(
            means=jnp.pad(self.means, ((0, pad), (0, 0))),
            log_scales=jnp.pad(self.log_scales, (0, pad)),
            logit_opacities=jnp.pad(self.logit_opacities, (0, pad)),
            rgb=jnp.pad(self.rgb, ((0, pad), (0, 0))),
            active=jnp.pad(self.active, (0, pad)),
        )


def check_gaussians(gaussians: Gaussians, name: str = "gaussians") -> None:
    """Shape/dtype checks (always) and finiteness of active slots (only for concrete arrays).

    Args:
      gaussians: the map to check.
      name: the argument's name in the error messages.

    Raises:
      ValueError: naming the offending field.
    """
    if not isinstance(gaussians, Gaussians):
        raise ValueError(f"{name} must be a gsjax.gaussians.Gaussians, got {type(gaussians).__name__}")
    means = gaussians.means
    if means.ndim != 2 or means.shape[-1] != 3:
        raise ValueError(f"{name}.means must have shape [N, 3], got {tuple(means.shape)}")
    n = means.shape[0]
    expected = {"log_scales": (n,), "logit_opacities": (n,), "rgb": (n, 3), "active": (n,)}
    for field, shape in expected.items():
        value = getattr(gaussians, field)
        if tuple(value.shape) != shape:
            raise ValueError(f"{name}.{field} must have shape {list(shape)}, got {list(value.shape)}")
    for field in ("means", "log_scales", "logit_opacities", "rgb"):
        if not jnp.issubdtype(getattr(gaussians, field).dtype, jnp.floating):
            raise ValueError(f"{name}.{field} must be floating point, got {getattr(gaussians, field).dtype}")
    if gaussians.active.dtype != jnp.bool_:
        raise ValueError(f"{name}.active must be bool, got {gaussians.active.dtype}")
    if not is_checkable(gaussians):
        return  # value checks need concrete arrays (skipped under an outer jit)
    active = np.asarray(gaussians.active)
    for field in ("means", "log_scales", "logit_opacities", "rgb"):
        value = np.asarray(getattr(gaussians, field))
        bad = ~np.isfinite(value.reshape(n, -1)).all(axis=1) & active
        if bad.any():
            raise ValueError(
                f"{name}.{field} has non-finite values in {int(bad.sum())} active slot(s), first at index "
                f"{int(np.argmax(bad))}"
            )


def gaussians_from_rgbd(
    color: jax.Array,
    depth: jax.Array,
    intrinsics: Intrinsics,
    c2w: jax.Array,
    mask: jax.Array | None = None,
    opacity: float = 0.5,
) -> Gaussians:
    """One Gaussian per valid depth pixel, SplaTAM's initialisation (method_spec A.4, A.7).

    Args:
      color: [H, W, 3] float colours in [0, 1].
      depth: [H, W] float depth (m); 0 marks an invalid pixel.
      intrinsics: the camera of the images.
      c2w: [4, 4] camera-to-world pose (m).
      mask: optional [H, W] bool restricting the pixels.
      opacity: initial opacity in (0, 1) (SplaTAM: 0.5, i.e. logit 0).

    Returns:
      Gaussians (float32) with H*W slots in row-major pixel order; slots of masked-out or invalid pixels are inactive.
        Centres are back-projected pixel centres (so each renders centred on its pixel); the isotropic scale is one
        pixel's footprint at that depth, ``z / ((fx + fy) / 2)``.
    """
    from gsjax.camera import backproject

    height, width = depth.shape
    points = backproject(depth, intrinsics).reshape(-1, 3)
    points = points @ c2w[:3, :3].T + c2w[:3, 3]
    z = depth.reshape(-1)
    valid = z > 0
    if mask is not None:
        valid &= mask.reshape(-1)
    scale = jnp.where(valid, z, 1.0) / (0.5 * (intrinsics.fx + intrinsics.fy))
    logit = jnp.log(opacity) - jnp.log1p(-opacity)
    return Gaussians(
        means=points.astype(jnp.float32),
        log_scales=jnp.log(scale).astype(jnp.float32),
        logit_opacities=jnp.full((height * width,), logit, jnp.float32),
        rgb=color.reshape(-1, 3).astype(jnp.float32),
        active=valid,
    )
