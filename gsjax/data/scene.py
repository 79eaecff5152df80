"""The analytic scene of the synthetic generator: a textured room with boxes and spheres, ray cast in numpy.

World frame: x, y horizontal, z up, metres. The room is the box ``ROOM_MIN..ROOM_MAX`` seen from inside (floor at
z = 0, ceiling at 2.6 m); a few axis-aligned boxes stand on the floor and spheres rest on them or hang. Surfaces
carry procedural solid textures (checkers, stripes and a sum of sinusoids: fixed, so the scene is identical in every
run) under a fixed Lambertian light, so that colour has gradients everywhere for photometric tracking.

Ray casting is exact and independent of any splatting renderer: for each ray the nearest positive hit among the
room's six planes (slab method, from inside), the boxes (slab method, from outside) and the spheres (quadratic).
"""

from __future__ import annotations

import numpy as np

ROOM_MIN = np.array([-2.5, -2.0, 0.0])
ROOM_MAX = np.array([2.5, 2.0, 2.6])
# Axis-aligned boxes (min corner, max corner), m.
BOXES = (
    (np.array([-1.9, 0.6, 0.0]), np.array([-1.0, 1.5, 0.9])),  # cabinet, left
    (np.array([0.5, 1.0, 0.0]), np.array([1.5, 1.8, 0.45])),  # low table, right
    (np.array([-0.3, 1.6, 0.0]), np.array([0.4, 2.0, 1.6])),  # shelf against the far wall
)
# Spheres (centre, radius), m.
SPHERES = (
    (np.array([0.0, 0.9, 0.35]), 0.35),  # on the floor
    (np.array([1.0, 1.4, 0.75]), 0.3),  # on the table
    (np.array([-1.45, 1.05, 1.15]), 0.25),  # on the cabinet
    (np.array([-0.6, 0.3, 1.9]), 0.2),  # hanging lamp
)
# Material ids: 0..5 room faces (-x, +x, -y, +y, floor -z, ceiling +z), then boxes, then spheres.
NUM_MATERIALS = 6 + len(BOXES) + len(SPHERES)
LIGHT_DIRECTION = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])


def _materials() -> dict[str, np.ndarray]:
    """Per-material texture parameters [NUM_MATERIALS, ...], from a fixed generator (the scene never changes)."""
    rng = np.random.default_rng(20240607)
    base = rng.uniform(0.15, 0.85, (NUM_MATERIALS, 2, 3))  # two colours per material, mixed by the pattern
    base[:, 1] = 0.35 * base[:, 1] + 0.65 * (1.0 - base[:, 0])  # make the two colours contrast
    return {
        "colors": base,
        "checker": rng.uniform(0.15, 0.5, NUM_MATERIALS),  # checker square size (m)
        "weights": rng.dirichlet((2.0, 1.0, 2.0), NUM_MATERIALS),  # checker, stripes, sinusoid noise
        "stripe_period": rng.uniform(0.08, 0.3, NUM_MATERIALS),  # m
        "stripe_axis": rng.integers(0, 3, NUM_MATERIALS),
    }


MATERIALS = _materials()
_NOISE_RNG = np.random.default_rng(7)
# Sum-of-sinusoids "noise": 8 plane waves with random directions, 2-9 cycles per metre, random phases.
_NOISE_WAVES = _NOISE_RNG.normal(size=(8, 3)) * (2 * np.pi * _NOISE_RNG.uniform(2.0, 9.0, (8, 1)) / np.sqrt(3))
_NOISE_PHASES = _NOISE_RNG.uniform(0, 2 * np.pi, 8)


def raycast(origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of rays ``origin + t d`` with t > 0.

    Args:
      origin: [3] ray origin (m), inside the room and outside every object.
      directions: [N, 3] ray directions (any length; t is in units of their length).

    Returns:
      t [N] float64 (finite: the room is closed) and material [N] int (see ``NUM_MATERIALS``).
    """
    d = np.asarray(directions, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        # Room from inside: per axis, the plane ahead in the direction of travel (3 candidates).
        candidates = [np.where(d > 0, (ROOM_MAX - origin) * inv, np.where(d < 0, (ROOM_MIN - origin) * inv, np.inf))]
        for lo, hi in BOXES:  # slab method from outside: entry = last slab entered, if before the first exit
            t1, t2 = (lo - origin) * inv, (hi - origin) * inv
            near, far = np.minimum(t1, t2), np.maximum(t1, t2)
            t_in = np.maximum(np.maximum(near[:, 0], near[:, 1]), near[:, 2])  # (faster than .max(axis=1))
            t_out = np.minimum(np.minimum(far[:, 0], far[:, 1]), far[:, 2])
            candidates.append(np.where((t_in <= t_out) & (t_in > 0), t_in, np.inf)[:, None])
    a = d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 2] ** 2
    for centre, radius in SPHERES:  # |o + t d - c|^2 = r^2, nearer root
        oc = origin - centre
        b = d @ oc
        disc = b * b - a * (oc @ oc - radius * radius)
        t_s = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        candidates.append(np.where((disc >= 0) & (t_s > 0), t_s, np.inf)[:, None])
    all_t = np.concatenate(candidates, axis=1)  # [N, 3 + boxes + spheres]
    nearest = np.argmin(all_t, axis=1)
    t = np.take_along_axis(all_t, nearest[:, None], axis=1)[:, 0]
    axis_positive = np.take_along_axis(d, np.minimum(nearest, 2)[:, None], axis=1)[:, 0] > 0
    material = np.where(nearest < 3, 2 * nearest + axis_positive, nearest + 3)
    return t, material


def surface_normals(points: np.ndarray, material: np.ndarray) -> np.ndarray:
    """Unit normals [N, 3] of surface points [N, 3] (m) on their materials [N]; they face the free space."""
    normal = np.zeros_like(points)
    room = material < 6
    axis, positive = material[room] // 2, material[room] % 2 == 1
    normal[np.flatnonzero(room), axis] = np.where(positive, -1.0, 1.0)  # room normals point inwards
    for k, (lo, hi) in enumerate(BOXES):
        on = np.flatnonzero(material == 6 + k)
        offset = (points[on] - 0.5 * (lo + hi)) / (0.5 * (hi - lo))  # +-1 on the faces
        face = np.argmax(np.abs(offset), axis=1)
        normal[on, face] = np.sign(offset[np.arange(on.size), face])
    for k, (centre, radius) in enumerate(SPHERES):
        on = material == 6 + len(BOXES) + k
        normal[on] = (points[on] - centre) / radius
    return normal


def shade(points: np.ndarray, material: np.ndarray) -> np.ndarray:
    """Colour [N, 3] in [0, 1] of surface points [N, 3] (m) on their materials [N]."""
    m = MATERIALS
    normal = surface_normals(points, material)
    inside = points - 1e-4 * normal  # just below the surface, so checker cells never flip on the boundary plane
    size = m["checker"][material][:, None]
    checker = (np.sum(np.floor(inside / size), axis=1) % 2).astype(np.float64)
    coordinate = inside[np.arange(len(points)), m["stripe_axis"][material]]
    stripes = 0.5 + 0.5 * np.tanh(4.0 * np.sin(2 * np.pi * coordinate / m["stripe_period"][material]))
    # float32 sines are ~15x faster than float64 here, and texture needs no more precision.
    noise = 0.5 + np.sin((points @ _NOISE_WAVES.T + _NOISE_PHASES).astype(np.float32)) @ np.full(8, 1 / 8, np.float32)
    w = m["weights"][material]
    pattern = np.clip(w[:, 0] * checker + w[:, 1] * stripes + w[:, 2] * noise, 0.0, 1.0)
    colors = m["colors"][material]
    albedo = colors[:, 0] + (colors[:, 1] - colors[:, 0]) * pattern[:, None]
    light = 0.7 + 0.3 * np.abs(normal @ LIGHT_DIRECTION)
    return np.clip(albedo * light[:, None], 0.0, 1.0)


def clearance(points: np.ndarray) -> np.ndarray:
    """Distance [N] (m) from points [N, 3] inside the room to the nearest surface of the scene (negative inside an
    object)."""
    p = np.asarray(points, np.float64)
    distance = np.minimum(np.min(p - ROOM_MIN, axis=1), np.min(ROOM_MAX - p, axis=1))
    for lo, hi in BOXES:
        outside = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
        inside = np.minimum(np.min(p - lo, axis=1), np.min(hi - p, axis=1))
        distance = np.minimum(distance, np.where(outside > 0, outside, -inside))
    for centre, radius in SPHERES:
        distance = np.minimum(distance, np.linalg.norm(p - centre, axis=1) - radius)
    return distance
