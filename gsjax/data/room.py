"""Realistic dense Gaussian maps of an analytic room, for rasterizer measurements (`gsjax bench`, experiments/).

A SplaTAM map is, to first order, one isotropic Gaussian per depth pixel with a one-pixel footprint
(scale = z / f), opacity rising from 0.5 towards 1 on surfaces during mapping and staying low at depth edges, plus
Gaussians that densification adds from later frames where the first ones leave holes. The scene is the synthetic
sequence's room (:mod:`gsjax.data.scene`, ray cast by :func:`gsjax.data.synthetic.render_view`) seen from that
sequence's first camera at the render resolution, so the map has the density SplaTAM would build there.

Variants:
  ``fresh``: frame-0 initialisation, opacity 0.5 everywhere (SplaTAM's init).
  ``mapped``: opacity 0.95 on surfaces, 0.3 within 2 px of depth discontinuities ("semi-transparent edges"),
    plus a second layer from a viewpoint 5 cm to the side, at opacity 0.5, where it lands off the first layer.
  ``layered``: three overlapping semi-transparent layers (opacity 0.3-0.6, from three viewpoints 3 cm apart):
    a worst case, with up to ~115 contributors per pixel before the transmittance falls below 1e-4 (at 80x60).
  ``receding``: the ``mapped`` map seen from 0.5 m further back than where it was built (a SLAM camera moving
    away from what it mapped: more, smaller Gaussians per pixel).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.camera import Intrinsics, invert_transform, make_intrinsics
from gsjax.data.synthetic import camera_trajectory, render_view
from gsjax.gaussians import Gaussians, gaussians_from_rgbd


def _viewpoint() -> np.ndarray:
    """[4, 4] camera-to-world of the view the maps are built around: the synthetic sequence's first camera."""
    return camera_trajectory(np.zeros(1))[0]


def _edge_mask(depth: np.ndarray, radius: int = 2, rel: float = 0.05) -> np.ndarray:
    """Pixels within ``radius`` of a depth discontinuity (relative jump > rel)."""
    edge = np.zeros(depth.shape, bool)
    for axis in (0, 1):
        jump = np.abs(np.diff(depth, axis=axis)) > rel * np.minimum(
            np.delete(depth, -1, axis), np.delete(depth, 0, axis)
        )
        pad = [(0, 0), (0, 0)]
        pad[axis] = (0, 1)
        edge |= np.pad(jump, pad)
        pad[axis] = (1, 0)
        edge |= np.pad(jump, pad)
    grown = edge.copy()
    for _ in range(radius - 1):
        grown[1:] |= grown[:-1].copy()
        grown[:-1] |= grown[1:].copy()
        grown[:, 1:] |= grown[:, :-1].copy()
        grown[:, :-1] |= grown[:, 1:].copy()
    return grown


def _layer(intrinsics, offset_x, opacity, rng) -> Gaussians:
    """One Gaussian per pixel of the room seen from the viewpoint moved ``offset_x`` m along its x axis."""
    c2w = _viewpoint() @ _translation(offset_x, 0.0, 0.0)
    color, depth = render_view(c2w, intrinsics)
    g = gaussians_from_rgbd(jnp.asarray(color), jnp.asarray(depth), intrinsics, jnp.asarray(c2w, jnp.float32))
    if callable(opacity):
        o = opacity(depth, rng)
    else:
        o = np.broadcast_to(np.asarray(opacity, np.float64), depth.shape)
    o = np.clip(o.reshape(-1), 1e-3, 0.999)
    return Gaussians(g.means, g.log_scales, jnp.asarray(np.log(o) - np.log1p(-o), jnp.float32), g.rgb, g.active)


def _concat(maps: list[Gaussians]) -> Gaussians:
    return Gaussians(*(jnp.concatenate([getattr(m, f) for m in maps]) for f in Gaussians.__dataclass_fields__))


def _translation(x: float, y: float, z: float) -> np.ndarray:
    moved = np.eye(4)
    moved[:3, 3] = (x, y, z)
    return moved


def room_intrinsics(height: int, width: int) -> Intrinsics:
    """The pinhole camera the room is mapped and seen with: about 64 degrees across, centred."""
    fx = 0.8 * width
    return make_intrinsics(fx, fx, (width - 1) / 2, (height - 1) / 2, height, width)


def dense_surface_map(height: int, width: int, variant: str = "mapped",
                      seed: int = 0) -> tuple[Gaussians, jax.Array, Intrinsics]:
    """(gaussians, w2c, intrinsics) of a SplaTAM-density map of the analytic room and the view it is seen from."""
    intrinsics = room_intrinsics(height, width)
    w2c = jnp.asarray(invert_transform(_viewpoint()), jnp.float32)
    rng = np.random.default_rng(seed)
    if variant == "fresh":
        maps = [_layer(intrinsics, 0.0, 0.5, rng)]
    elif variant == "mapped":

        def surface(depth, rng):
            return np.where(_edge_mask(depth), 0.3, 0.95)

        maps = [
            _layer(intrinsics, 0.0, surface, rng),
            _layer(intrinsics, 0.05, 0.5, rng),
        ]
        # Keep the second layer only where it does not sit on top of the first (densification fills holes).
        first = maps[0]
        second = maps[1]
        keep = jnp.asarray(rng.uniform(size=second.active.shape) < 0.15) & second.active
        maps = [first, Gaussians(second.means, second.log_scales, second.logit_opacities, second.rgb, keep)]
    elif variant == "receding":
        gaussians, _, intrinsics = dense_surface_map(height, width, "mapped", seed)
        back = invert_transform(_viewpoint() @ _translation(0.0, 0.0, -0.5))
        return gaussians, jnp.asarray(back, jnp.float32), intrinsics
    elif variant == "layered":

        def semi(depth, rng):
            return rng.uniform(0.3, 0.6, depth.shape)

        maps = [_layer(intrinsics, dx, semi, rng) for dx in (0.0, 0.03, -0.03)]
    else:
        raise ValueError(f"unknown map variant {variant!r} (fresh, mapped, layered, receding)")
    return _concat(maps), w2c, intrinsics
