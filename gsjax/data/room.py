"""Realistic dense Gaussian maps of an analytic room, for rasterizer measurements (`gsjax bench`, experiments/).

A SplaTAM map is, to first order, one isotropic Gaussian per depth pixel with a one-pixel footprint
(scale = z / f), opacity rising from 0.5 towards 1 on surfaces during mapping and staying low at depth edges, plus
Gaussians that densification adds from later frames where the first ones leave holes. The scene here is an
analytic room corner (back wall, floor, a box, a sphere) ray cast at the render resolution, so the map has the
density SplaTAM would build at that resolution.

Variants:
  ``fresh``: frame-0 initialisation, opacity 0.5 everywhere (SplaTAM's init).
  ``mapped``: opacity 0.95 on surfaces, 0.3 within 2 px of depth discontinuities ("semi-transparent edges"),
    plus a second layer from a viewpoint 5 cm to the side, at opacity 0.5, where it lands off the first layer.
  ``layered``: three overlapping semi-transparent layers (opacity 0.3-0.6, from three viewpoints 3 cm apart):
    a worst case, with ~80-110 contributors per pixel before the transmittance falls below 1e-4.
  ``receding``: the ``mapped`` map seen from 0.5 m further back than where it was built (a SLAM camera moving
    away from what it mapped: more, smaller Gaussians per pixel).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from gsjax.camera import make_intrinsics
from gsjax.gaussians import Gaussians, gaussians_from_rgbd


def _ray_cast(height: int, width: int, fx: float, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth [H, W] (z, m) and colour [H, W, 3] of the analytic room from a camera-to-world pose."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    dirs_cam = np.stack([(u - (width - 1) / 2) / fx, (v - (height - 1) / 2) / fx, np.ones_like(u)], -1)
    dirs = dirs_cam @ c2w[:3, :3].T
    origin = c2w[:3, 3]
    best = np.full((height, width), np.inf)
    color = np.zeros((height, width, 3))

    def hit(t, rgb):
        nonlocal best, color
        t = np.where(t > 1e-6, t, np.inf)
        closer = t < best
        best = np.where(closer, t, best)
        color = np.where(closer[..., None], rgb, color)

    def texture(p, a, b):
        checker = (np.floor(p[..., a] * 4) + np.floor(p[..., b] * 4)) % 2
        return 0.25 + 0.5 * checker[..., None] * np.array([0.9, 0.6, 0.3]) + 0.2 * np.sin(p[..., a:a + 1] * 9)

    # Back wall z = 3.0 and floor y = 0.8 (camera looks along +z, y down).
    for axis, level, a, b in ((2, 3.0, 0, 1), (1, 0.8, 0, 2)):
        t = (level - origin[axis]) / np.where(np.abs(dirs[..., axis]) > 1e-9, dirs[..., axis], 1e-9)
        p = origin + t[..., None] * dirs
        hit(t, texture(p, a, b))
    # Axis-aligned box [-0.6,-0.1] x [0.2,0.8] x [1.6,2.1] (slab test).
    lo, hi = np.array([-0.6, 0.2, 1.6]), np.array([-0.1, 0.8, 2.1])
    safe = np.where(np.abs(dirs) > 1e-9, dirs, 1e-9)
    t0, t1 = (lo - origin) / safe, (hi - origin) / safe
    tn, tf = np.minimum(t0, t1).max(-1), np.maximum(t0, t1).min(-1)
    t_box = np.where((tn <= tf) & (tf > 0), tn, np.inf)
    hit(t_box, texture(origin + t_box[..., None] * dirs, 0, 2) * np.array([0.5, 0.8, 1.0]))
    # Sphere at (0.5, 0.3, 2.2), radius 0.35.
    oc = origin - np.array([0.5, 0.3, 2.2])
    bq = np.sum(dirs * oc, -1)
    cq = np.sum(oc * oc) - 0.35**2
    aq = np.sum(dirs * dirs, -1)
    disc = bq * bq - aq * cq
    t_sph = np.where(disc > 0, (-bq - np.sqrt(np.maximum(disc, 0))) / aq, np.inf)
    hit(t_sph, np.broadcast_to(np.array([0.8, 0.2, 0.2]), color.shape) * (0.7 + 0.3 * dirs[..., 1:2] ** 2))
    depth = best * np.sum(dirs * c2w[:3, 2], -1)  # ray length * cos -> z along the optical axis
    return np.where(np.isfinite(depth), depth, 0.0), np.clip(color, 0, 1)


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


def _layer(height, width, fx, intrinsics, offset_x, opacity, rng) -> Gaussians:
    c2w = np.eye(4)
    c2w[0, 3] = offset_x
    with np.errstate(invalid="ignore"):  # rays that miss a surface carry inf
        depth, color = _ray_cast(height, width, fx, c2w)
    g = gaussians_from_rgbd(jnp.asarray(color), jnp.asarray(depth), intrinsics, jnp.asarray(c2w, jnp.float32))
    if callable(opacity):
        o = opacity(depth, rng)
    else:
        o = np.broadcast_to(np.asarray(opacity, np.float64), depth.shape)
    o = np.clip(o.reshape(-1), 1e-3, 0.999)
    return Gaussians(g.means, g.log_scales, jnp.asarray(np.log(o) - np.log1p(-o), jnp.float32), g.rgb, g.active)


def _concat(maps: list[Gaussians]) -> Gaussians:
    return Gaussians(*(jnp.concatenate([getattr(m, f) for m in maps]) for f in Gaussians.__dataclass_fields__))


def room_intrinsics(height: int, width: int):
    """The pinhole camera the room is mapped and seen with: about 64 degrees across, centred."""
    fx = 0.8 * width
    return make_intrinsics(fx, fx, (width - 1) / 2, (height - 1) / 2, height, width)


def dense_surface_map(height: int, width: int, variant: str = "mapped", seed: int = 0):
    """(gaussians, w2c, intrinsics) of a SplaTAM-density map of the analytic room, seen from the origin."""
    intrinsics = room_intrinsics(height, width)
    fx = float(intrinsics.fx)
    rng = np.random.default_rng(seed)
    if variant == "fresh":
        maps = [_layer(height, width, fx, intrinsics, 0.0, 0.5, rng)]
    elif variant == "mapped":

        def surface(depth, rng):
            return np.where(_edge_mask(depth), 0.3, 0.95)

        maps = [
            _layer(height, width, fx, intrinsics, 0.0, surface, rng),
            _layer(height, width, fx, intrinsics, 0.05, 0.5, rng),
        ]
        # Keep the second layer only where it does not sit on top of the first (densification fills holes).
        first = maps[0]
        second = maps[1]
        keep = jnp.asarray(rng.uniform(size=second.active.shape) < 0.15) & second.active
        maps = [first, Gaussians(second.means, second.log_scales, second.logit_opacities, second.rgb, keep)]
    elif variant == "receding":
        gaussians, _, intrinsics = dense_surface_map(height, width, "mapped", seed)
        w2c = np.eye(4)
        w2c[2, 3] = 0.5  # camera at z = -0.5 in the world
        return gaussians, jnp.asarray(w2c, jnp.float32), intrinsics
    elif variant == "layered":

        def semi(depth, rng):
            return rng.uniform(0.3, 0.6, depth.shape)

        maps = [_layer(height, width, fx, intrinsics, dx, semi, rng) for dx in (0.0, 0.03, -0.03)]
    else:
        raise ValueError(f"unknown map variant {variant!r} (fresh, mapped, layered, receding)")
    return _concat(maps), jnp.eye(4, dtype=jnp.float32), intrinsics
