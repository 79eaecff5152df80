"""Tiny synthetic scenes for the rasterizer tests: each is a function of a seed returning (gaussians, w2c, intrinsics).

Gaussians are placed in the camera frame (where their screen footprint is easy to control: centre in px,
scale in px) and then moved to the world frame with a random camera pose, so every scene also exercises the
world-to-camera transform. Images are small (32 x 40 by default) so the dense reference stays fast; the
capacities are few (64 for the small scenes) so that the renderer compiles few distinct shapes.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import scipy.linalg

from gsjax.camera import Intrinsics, make_intrinsics
from gsjax.gaussians import Gaussians

HEIGHT, WIDTH = 32, 40
FX, FY, CX, CY = 36.0, 36.0, 19.3, 15.6
SMALL_CAPACITY = 64


# ----------------------------------------------------------------------------------------------- geometry (f64)


def hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def se3_exp_np(delta: np.ndarray) -> np.ndarray:
    """Tangent (rho, phi) -> 4x4 transform, as the matrix exponential of the twist (float64, independent of gsjax)."""
    delta = np.asarray(delta, np.float64)
    twist = np.zeros((4, 4))
    twist[:3, :3] = hat(delta[3:])
    twist[:3, 3] = delta[:3]
    return scipy.linalg.expm(twist)


def random_rotation(rng: np.random.Generator, max_angle: float = np.pi) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return scipy.linalg.expm(hat(axis * rng.uniform(0.0, max_angle)))


def rigid(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, translation
    return out


def look_at_w2c(eye, target, up) -> np.ndarray:
    """World-to-camera pose of an OpenCV camera (x right, y down, z forward) at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    y = -up + np.dot(up, z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    rot = np.stack([x, y, z])  # rows: camera axes in world coordinates = R_w2c
    return rigid(rot, -rot @ eye)


def random_c2w(rng: np.random.Generator, max_angle: float = 0.6, max_translation: float = 1.0) -> np.ndarray:
    return rigid(random_rotation(rng, max_angle), rng.uniform(-max_translation, max_translation, 3))


def camera_points(uv: np.ndarray, z: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Camera-frame points [n, 3] whose projection is ``uv`` [n, 2] (px) at depth ``z`` [n] (m)."""
    return np.stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z], axis=-1)


def to_world(points_cam: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    return points_cam @ c2w[:3, :3].T + c2w[:3, 3]


def default_intrinsics(height: int = HEIGHT, width: int = WIDTH) -> Intrinsics:
    return make_intrinsics(FX, FY, CX, CY, height, width)


def separate_depths(points_cam: np.ndarray, min_gap: float = 1e-5) -> np.ndarray:
    """Slide points along their viewing rays so that no two depths are closer than ``min_gap`` (m).

    Depth ties make the front-to-back order, and so the image, depend on float rounding (DESIGN: scenes avoid
    them); 1e-5 m is ~100 float32 ulps at 1 m.
    """
    z = points_cam[:, 2]
    order = np.argsort(z, kind="stable")
    zs = z[order].copy()
    for i in range(1, len(zs)):
        if zs[i] - zs[i - 1] < min_gap and zs[i - 1] > -min_gap:  # leave points far behind the camera alone
            zs[i] = zs[i - 1] + min_gap
    new_z = np.empty_like(z)
    new_z[order] = zs
    ratio = np.where(z != 0, new_z / np.where(z != 0, z, 1.0), 1.0)
    return points_cam * ratio[:, None]


def _scene(points_cam, rgb, sigma_px, opacity, c2w, intrinsics, capacity=SMALL_CAPACITY):
    """Build a scene from camera-frame points and screen-space sizes (sigma in px at the Gaussian's depth)."""
    fx, fy = float(intrinsics.fx), float(intrinsics.fy)
    points_cam = separate_depths(points_cam)
    scales = np.asarray(sigma_px, np.float64) * np.abs(points_cam[:, 2]) / (0.5 * (fx + fy))
    gaussians = Gaussians.create(to_world(points_cam, c2w), rgb, scales, opacity, capacity=capacity)
    return gaussians, jnp.asarray(np.linalg.inv(c2w), jnp.float32), intrinsics


# ----------------------------------------------------------------------------------------------- scenes


def sparse_random(seed: int = 0):
    """24 Gaussians scattered in the frustum (z 0.8-3 m), 1-6 px wide, opacity 0.2-0.9; 40 free slots."""
    rng = np.random.default_rng(seed)
    intr = default_intrinsics()
    n = 24
    uv = rng.uniform([-4, -4], [WIDTH + 4, HEIGHT + 4], (n, 2))
    pts = camera_points(uv, rng.uniform(0.8, 3.0, n), FX, FY, CX, CY)
    return _scene(pts, rng.uniform(0, 1, (n, 3)), rng.uniform(1, 6, n), rng.uniform(0.2, 0.9, n), random_c2w(rng), intr)


def dense_surface(seed: int = 0):
    """An opaque textured surface, one Gaussian per pixel as SplaTAM initialises a map (1280 Gaussians).

    A tilted plane (z 1.2-2 m) partly occluded by a sphere (radius 0.25 m at z ~1 m); each pixel (jittered by
    +-0.25 px) is back-projected at the surface depth; scale = z / f (one pixel's footprint), opacity 0.9-0.98.
    """
    rng = np.random.default_rng(seed)
    intr = default_intrinsics()
    rows, cols = np.meshgrid(np.arange(HEIGHT), np.arange(WIDTH), indexing="ij")
    uv = np.stack([cols.ravel(), rows.ravel()], -1) + rng.uniform(-0.25, 0.25, (HEIGHT * WIDTH, 2))
    rays = np.stack([(uv[:, 0] - CX) / FX, (uv[:, 1] - CY) / FY, np.ones(len(uv))], -1)
    # plane: n . x = d with normal tilted about x and y
    normal = np.array([0.25, -0.3, 1.0])
    z_plane = 1.5 / (rays @ normal)
    centre, radius = np.array([0.12, 0.05, 1.05]), 0.25
    b = rays @ centre
    disc = b**2 - np.sum(rays**2, -1) * (centre @ centre - radius**2)
    z_sphere = np.where(disc > 0, (b - np.sqrt(np.maximum(disc, 0))) / np.sum(rays**2, -1), np.inf)
    z = np.minimum(z_plane, z_sphere)
    pts = rays * z[:, None]
    texture = 0.5 + 0.5 * np.sin(np.stack([3 * pts[:, 0], 5 * pts[:, 1], 4 * (pts[:, 0] + pts[:, 2])], -1) * 6)
    rgb = np.clip(texture + rng.normal(0, 0.05, texture.shape), 0, 1)
    return _scene(pts, rgb, np.ones(len(pts)), rng.uniform(0.9, 0.98, len(pts)), random_c2w(rng), intr, capacity=None)


def heavy_overlap(seed: int = 0):
    """Nine semi-transparent layers (opacity 0.3-0.6) of 7 wide Gaussians (10-18 px): every pixel has ~63
    candidates and 25-62 contributors before T < 1e-4 (the walk stops at most pixels). 63 Gaussians, 64 slots.

    Also the truncation scene: with a few slots per pixel or per tile, every pixel overflows.
    """
    rng = np.random.default_rng(seed)
    intr = default_intrinsics()
    layers, per_layer = 9, 7
    pts, sig = [], []
    for layer in range(layers):
        z = 1.0 + 0.15 * layer + rng.uniform(-0.02, 0.02, per_layer)
        uv = rng.uniform([-2, -2], [WIDTH + 2, HEIGHT + 2], (per_layer, 2))
        pts.append(camera_points(uv, z, FX, FY, CX, CY))
        sig.append(rng.uniform(10.0, 18.0, per_layer))
    pts, sig = np.concatenate(pts), np.concatenate(sig)
    n = len(pts)
    return _scene(pts, rng.uniform(0, 1, (n, 3)), sig, rng.uniform(0.3, 0.6, n), random_c2w(rng), intr)


def near_plane(seed: int = 0):
    """Gaussians around and behind the near plane (0.2 m) plus a background.

    In front of the camera: centres at z in {0.12, 0.17, 0.195} (culled) and {0.205, 0.23, 0.3} (kept), all with
    3D extents straddling z = 0.2; behind the camera (z in [-2, -0.05]) and at z ~ 0, with centres that
    would project inside the image and wide footprints if they were not culled.
    """
    rng = np.random.default_rng(seed)
    intr = default_intrinsics()
    c2w = random_c2w(rng)
    near_z = np.array([0.12, 0.17, 0.195, 0.205, 0.23, 0.3])
    uv_near = rng.uniform([5, 5], [WIDTH - 5, HEIGHT - 5], (len(near_z), 2))
    pts_near = camera_points(uv_near, near_z, FX, FY, CX, CY)
    sig_near = rng.uniform(2.0, 5.0, len(near_z))  # scale ~ 0.01-0.04 m: straddles the plane for z near 0.2
    behind_z = np.concatenate([rng.uniform(-2.0, -0.05, 5), [1e-3, -1e-3]])
    uv_behind = rng.uniform([5, 5], [WIDTH - 5, HEIGHT - 5], (len(behind_z), 2))
    pts_behind = camera_points(uv_behind, behind_z, FX, FY, CX, CY)
    sig_behind = np.full(len(behind_z), 20.0)
    bg_n = 12
    uv_bg = rng.uniform([0, 0], [WIDTH, HEIGHT], (bg_n, 2))
    pts_bg = camera_points(uv_bg, rng.uniform(1.0, 2.0, bg_n), FX, FY, CX, CY)
    pts = np.concatenate([pts_near, pts_behind, pts_bg])
    sig = np.concatenate([sig_near, np.abs(sig_behind), rng.uniform(3, 8, bg_n)])
    n = len(pts)
    return _scene(pts, rng.uniform(0, 1, (n, 3)), sig, rng.uniform(0.4, 0.9, n), c2w, intr)


def off_screen(seed: int = 0):
    """Gaussians centred outside the image (up to x/z = 2.5, far past the 1.3 tan(fov/2) Jacobian clamp) whose
    wide footprints reach into it, plus a few in view."""
    rng = np.random.default_rng(seed)
    intr = default_intrinsics()
    n_out = 16
    side = rng.integers(0, 4, n_out)
    dist = rng.uniform(4.0, 60.0, n_out)  # px outside the border
    along = rng.uniform(0, 1, n_out)
    u = np.where(side == 0, -dist, np.where(side == 1, WIDTH - 1 + dist, along * WIDTH))
    v = np.where(side == 2, -dist, np.where(side == 3, HEIGHT - 1 + dist, along * HEIGHT))
    pts_out = camera_points(np.stack([u, v], -1), rng.uniform(0.8, 2.5, n_out), FX, FY, CX, CY)
    sig_out = dist * rng.uniform(0.5, 0.9, n_out) + 3.0
    n_in = 6
    pts_in = camera_points(rng.uniform([0, 0], [WIDTH, HEIGHT], (n_in, 2)), rng.uniform(1.5, 3, n_in), FX, FY, CX, CY)
    pts = np.concatenate([pts_out, pts_in])
    sig = np.concatenate([sig_out, rng.uniform(2, 6, n_in)])
    n = len(pts)
    return _scene(pts, rng.uniform(0, 1, (n, 3)), sig, rng.uniform(0.4, 0.9, n), random_c2w(rng), intr)


def tiny_and_huge(seed: int = 0):
    """Sub-pixel Gaussians (0.02-0.3 px, where the 0.3 px^2 dilation dominates) in front of three huge ones
    (100-300 px) that cover the whole image."""
    rng = np.random.default_rng(seed)
    intr = default_intrinsics()
    n_tiny, n_huge = 30, 3
    uv_tiny = rng.uniform([-1, -1], [WIDTH, HEIGHT], (n_tiny, 2))
    pts_tiny = camera_points(uv_tiny, rng.uniform(0.5, 1.5, n_tiny), FX, FY, CX, CY)
    uv_huge = rng.uniform([0, 0], [WIDTH, HEIGHT], (n_huge, 2))
    pts_huge = camera_points(uv_huge, rng.uniform(2.5, 4, n_huge), FX, FY, CX, CY)
    pts = np.concatenate([pts_tiny, pts_huge])
    sig = np.concatenate([rng.uniform(0.02, 0.3, n_tiny), rng.uniform(100, 300, n_huge)])
    opa = np.concatenate([rng.uniform(0.5, 0.95, n_tiny), rng.uniform(0.3, 0.7, n_huge)])
    n = len(pts)
    return _scene(pts, rng.uniform(0, 1, (n, 3)), sig, opa, random_c2w(rng), intr)


def rotated_camera(seed: int = 0):
    """A 45 x 60 image (no side a multiple of 8 or 16) with fx != fy, off-centre principal point, looking at a
    world cluster of 40 Gaussians from a strongly rotated and translated pose (look-at plus roll)."""
    rng = np.random.default_rng(seed)
    intr = make_intrinsics(50.0, 46.0, 31.2, 21.7, 45, 60)
    target = np.array([0.4, -0.3, 2.0])
    n = 40
    means = target + rng.uniform(-0.5, 0.5, (n, 3))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    eye = target + 1.8 * direction
    w2c = look_at_w2c(eye, target, rng.normal(size=3))
    roll = rigid(random_rotation(rng, 0.3), np.zeros(3))
    w2c = roll @ w2c
    cam = separate_depths(means @ w2c[:3, :3].T + w2c[:3, 3])
    means = to_world(cam, np.linalg.inv(w2c))
    scales = rng.uniform(0.04, 0.15, n)
    gaussians = Gaussians.create(means, rng.uniform(0, 1, (n, 3)), scales, rng.uniform(0.3, 0.9, n), capacity=64)
    return gaussians, jnp.asarray(w2c, jnp.float32), intr


def inactive_garbage(seed: int = 0):
    """20 active Gaussians scattered over 64 slots; the 44 free slots hold finite garbage that would cover the
    image (centres in view at 1 m, scales up to e^3 m, logit opacities up to 20, colours +-100) if rendered."""
    rng = np.random.default_rng(seed)
    gaussians, w2c, intr = sparse_random(seed + 1000)
    n_active = 20
    c2w = np.linalg.inv(np.asarray(w2c, np.float64))
    slots = rng.permutation(SMALL_CAPACITY)
    src = np.arange(n_active)
    active = np.zeros(SMALL_CAPACITY, bool)
    active[slots[:n_active]] = True
    garbage_uv = rng.uniform([0, 0], [WIDTH, HEIGHT], (SMALL_CAPACITY, 2))
    garbage_cam = camera_points(garbage_uv, np.ones(SMALL_CAPACITY), FX, FY, CX, CY)

    def place(field, garbage):
        out = np.array(garbage, np.float32)
        out[slots[:n_active]] = np.asarray(field)[src]
        return jnp.asarray(out)

    g = Gaussians(
        means=place(gaussians.means, to_world(garbage_cam, c2w)),
        log_scales=place(gaussians.log_scales, rng.uniform(-1, 3, SMALL_CAPACITY)),
        logit_opacities=place(gaussians.logit_opacities, rng.uniform(-5, 20, SMALL_CAPACITY)),
        rgb=place(gaussians.rgb, rng.uniform(-100, 100, (SMALL_CAPACITY, 3))),
        active=jnp.asarray(active),
    )
    return g, w2c, intr


SCENES = {
    "sparse_random": sparse_random,
    "dense_surface": dense_surface,
    "heavy_overlap": heavy_overlap,
    "near_plane": near_plane,
    "off_screen": off_screen,
    "tiny_and_huge": tiny_and_huge,
    "rotated_camera": rotated_camera,
    "inactive_garbage": inactive_garbage,
}


# ----------------------------------------------------------------------------------------------- gradient scenes
# Same shapes for all (24 x 32 image, 32 slots) so the differentiated renderer compiles once. Opacities stay
# below 0.99, so o g < 0.99 everywhere and the alpha clamp never acts (finite differences cannot see its
# straight-through gradient; that is tested separately).

GRAD_HEIGHT, GRAD_WIDTH, GRAD_CAPACITY = 24, 32, 32
GRAD_FX, GRAD_FY, GRAD_CX, GRAD_CY = 30.0, 28.0, 15.2, 11.7


def _grad_scene(rng, pts, sig, opa):
    intr = make_intrinsics(GRAD_FX, GRAD_FY, GRAD_CX, GRAD_CY, GRAD_HEIGHT, GRAD_WIDTH)
    n = len(pts)
    g, w2c, intr = _scene(pts, rng.uniform(0, 1, (n, 3)), sig, opa, random_c2w(rng), intr, capacity=GRAD_CAPACITY)
    # garbage (finite) in the free slots, so "no gradient to inactive slots" is not trivially true
    free = ~np.asarray(g.active)
    k = int(free.sum())

    def fill(field, garbage):
        out = np.array(field)
        out[free] = garbage
        return jnp.asarray(out, jnp.float32)

    centre = to_world(np.array([[0.0, 0.0, 1.5]]), np.linalg.inv(np.asarray(w2c, np.float64)))[0]
    g = dataclasses.replace(
        g,
        means=fill(g.means, centre + rng.normal(0, 0.2, (k, 3))),
        log_scales=fill(g.log_scales, rng.uniform(-3, 0, k)),
        logit_opacities=fill(g.logit_opacities, rng.uniform(-1, 3, k)),
        rgb=fill(g.rgb, rng.uniform(0, 1, (k, 3))),
    )
    return g, w2c, intr


def grad_sparse(seed: int = 0):
    """14 overlapping Gaussians (2-6 px, opacity 0.3-0.85) in view."""
    rng = np.random.default_rng(seed)
    n = 14
    uv = rng.uniform([0, 0], [GRAD_WIDTH, GRAD_HEIGHT], (n, 2))
    pts = camera_points(uv, rng.uniform(1.0, 3.0, n), GRAD_FX, GRAD_FY, GRAD_CX, GRAD_CY)
    return _grad_scene(rng, pts, rng.uniform(2, 6, n), rng.uniform(0.3, 0.85, n))


def grad_off_screen(seed: int = 0):
    """8 Gaussians in view and 6 off screen past the Jacobian clamp with footprints reaching in."""
    rng = np.random.default_rng(seed)
    n_in, n_out = 8, 6
    uv_in = rng.uniform([0, 0], [GRAD_WIDTH, GRAD_HEIGHT], (n_in, 2))
    side = np.arange(n_out) % 4
    dist = rng.uniform(12, 25, n_out)
    along = rng.uniform(0.2, 0.8, n_out)
    u = np.where(side == 0, -dist, np.where(side == 1, GRAD_WIDTH - 1 + dist, along * GRAD_WIDTH))
    v = np.where(side == 2, -dist, np.where(side == 3, GRAD_HEIGHT - 1 + dist, along * GRAD_HEIGHT))
    uv = np.concatenate([uv_in, np.stack([u, v], -1)])
    pts = camera_points(uv, rng.uniform(1.0, 2.5, n_in + n_out), GRAD_FX, GRAD_FY, GRAD_CX, GRAD_CY)
    sig = np.concatenate([rng.uniform(2, 6, n_in), dist * 0.8])
    return _grad_scene(rng, pts, sig, rng.uniform(0.4, 0.85, n_in + n_out))


def grad_stop_rule(seed: int = 0):
    """Five stacked layers of wide, nearly opaque Gaussians (opacity 0.93-0.97): the T < 1e-4 stop acts at most
    pixels."""
    rng = np.random.default_rng(seed)
    layers, per_layer = 5, 3
    pts, sig = [], []
    for layer in range(layers):
        uv = rng.uniform([4, 4], [GRAD_WIDTH - 4, GRAD_HEIGHT - 4], (per_layer, 2))
        z = 1.0 + 0.3 * layer + rng.uniform(-0.05, 0.05, per_layer)
        pts.append(camera_points(uv, z, GRAD_FX, GRAD_FY, GRAD_CX, GRAD_CY))
        sig.append(rng.uniform(10, 16, per_layer))
    pts, sig = np.concatenate(pts), np.concatenate(sig)
    return _grad_scene(rng, pts, sig, rng.uniform(0.93, 0.97, len(pts)))


GRADIENT_SCENES = {"grad_sparse": grad_sparse, "grad_off_screen": grad_off_screen, "grad_stop_rule": grad_stop_rule}
