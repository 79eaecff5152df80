"""Dense float64 reference renderer: the definition of correctness for ``gsjax.raster.render``.

Written from the rasterizer contract (DESIGN 2.2 / 2.2.1, spec A.3), independently of the tile-based
implementation. Every pixel is evaluated against every Gaussian; nothing is tiled, nothing is truncated unless
``max_contributors`` is given.

Semantics:

* camera point ``x_c = R mu + t`` (``w2c``), ``z = x_c[2]``; inactive slots and Gaussians with ``z <= near`` are
  skipped;
* centre ``u = fx X/Z + cx``, ``v = fy Y/Z + cy``; pixel (row i, column j) is evaluated at ``(u, v) = (j, i)``;
* ``Sigma2D = s^2 J J^T + 0.3 I`` with the perspective Jacobian ``J`` evaluated at x/z, y/z clamped to
  ``+-1.3 tan(fov/2)`` (``tan(fov_x/2) = W / (2 fx)``); the centre is not clamped;
* ``alpha = min(0.99, o exp(-0.5 d^T Sigma2D^-1 d))``; a Gaussian is a candidate at a pixel iff ``alpha >= 1/255``;
* front to back in increasing z, ``T = 1``; per candidate: if ``T (1 - alpha) < 1e-4`` the walk STOPS (this
  Gaussian and all later ones are not added); otherwise ``w = alpha T`` is accumulated and ``T *= 1 - alpha``;
* color = sum w rgb, depth = sum w z, silhouette = sum w, depth_sq = sum w z^2; background 0.

Besides the images the reference returns the discrete state of the walk (who contributed, whose alpha was
clamped, which Jacobians were clamped, the depth order), so gradient tests can check that finite differences
do not straddle a discontinuity, and per-pixel contributor counts, so truncation tests know what to expect.
"""

from __future__ import annotations

import dataclasses

import numpy as np

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_STOP = 1e-4
DILATION = 0.3
JACOBIAN_CLAMP = 1.3


@dataclasses.dataclass
class Projected:
    """Per-Gaussian screen-space quantities (float64; entries of culled slots are meaningless)."""

    visible: np.ndarray  # [N] bool: active and z > near
    z: np.ndarray  # [N] camera depth (m)
    uv: np.ndarray  # [N, 2] centre (px)
    cov2d: np.ndarray  # [N, 2, 2] dilated 2D covariance (px^2)
    conic: np.ndarray  # [N, 2, 2] its inverse
    opacity: np.ndarray  # [N]
    rgb: np.ndarray  # [N, 3]
    jacobian_clamped: np.ndarray  # [N, 2] bool: x/z resp. y/z hit the clamp


@dataclasses.dataclass
class ReferenceRender:
    """Images [H, W(, 3)] and the per-pixel discrete state of the front-to-back walk (float64 / bool / int)."""

    color: np.ndarray
    depth: np.ndarray
    silhouette: np.ndarray
    depth_sq: np.ndarray
    transmittance: np.ndarray  # [H, W] T left at the end of the walk
    contributors: np.ndarray  # [H, W, N] bool: Gaussian (slot index) was added at the pixel
    clamped: np.ndarray  # [H, W, N] bool: added with o g > 0.99 (alpha clamped)
    candidates: np.ndarray  # [H, W, N] bool: alpha >= 1/255, whether or not the walk reached it
    count: np.ndarray  # [H, W] int: number of contributors (added Gaussians)
    num_candidates: np.ndarray  # [H, W] int
    stopped: np.ndarray  # [H, W] bool: the walk ended by the T < 1e-4 rule
    cut: np.ndarray  # [H, W] bool: the walk ended because max_contributors was reached with more to add
    ambiguous: np.ndarray  # [H, W] bool: a discrete decision lies within float32 noise of its threshold
    projected: Projected
    order: np.ndarray  # [V] slot indices of the visible Gaussians, front to back

    def outputs(self) -> dict[str, np.ndarray]:
        return dict(color=self.color, depth=self.depth, silhouette=self.silhouette, depth_sq=self.depth_sq)

    def discrete_state(self) -> tuple[np.ndarray, ...]:
        """Everything that, if it changed between two parameter values, makes the images non-smooth between them."""
        p = self.projected
        return (self.contributors, self.clamped, self.order, p.visible, p.jacobian_clamped, self.stopped, self.cut)


def _f64(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Numerically stable logistic function."""
    x = _f64(x)
    e = np.exp(-np.abs(x))
    return np.where(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e))


def project(gaussians, w2c, intrinsics, near: float = 0.2, jacobian_clamp: bool = True) -> Projected:
    """World Gaussians -> screen-space centres, dilated EWA covariances and conics (float64)."""
    means, log_scales = _f64(gaussians.means), _f64(gaussians.log_scales)
    active = np.asarray(gaussians.active).astype(bool)
    w2c = _f64(w2c)
    fx, fy, cx, cy = (float(np.asarray(getattr(intrinsics, k))) for k in ("fx", "fy", "cx", "cy"))
    height, width = int(intrinsics.height), int(intrinsics.width)

    xc = means @ w2c[:3, :3].T + w2c[:3, 3]
    x, y, z = xc[:, 0], xc[:, 1], xc[:, 2]
    visible = active & (z > near)
    zs = np.where(visible, z, 1.0)  # keep culled slots finite; they are never used
    uv = np.stack([fx * x / zs + cx, fy * y / zs + cy], axis=-1)

    lim_x = JACOBIAN_CLAMP * width / (2.0 * fx)
    lim_y = JACOBIAN_CLAMP * height / (2.0 * fy)
    xz, yz = x / zs, y / zs
    clamped = np.stack([np.abs(xz) > lim_x, np.abs(yz) > lim_y], axis=-1) & visible[:, None]
    if jacobian_clamp:
        xz, yz = np.clip(xz, -lim_x, lim_x), np.clip(yz, -lim_y, lim_y)
    tx, ty = zs * xz, zs * yz
    jac = np.zeros((means.shape[0], 2, 3))
    jac[:, 0, 0] = fx / zs
    jac[:, 0, 2] = -fx * tx / zs**2
    jac[:, 1, 1] = fy / zs
    jac[:, 1, 2] = -fy * ty / zs**2
    scale_sq = np.exp(2.0 * log_scales)
    cov = scale_sq[:, None, None] * (jac @ np.swapaxes(jac, -1, -2)) + DILATION * np.eye(2)
    cov = np.where(visible[:, None, None], cov, np.eye(2))
    conic = np.linalg.inv(cov)
    return Projected(
        visible=visible,
        z=z,
        uv=uv,
        cov2d=cov,
        conic=conic,
        opacity=sigmoid(gaussians.logit_opacities),
        rgb=_f64(gaussians.rgb),
        jacobian_clamped=clamped,
    )


def render_reference(
    gaussians,
    w2c,
    intrinsics,
    near: float = 0.2,
    max_contributors: int | None = None,
    jacobian_clamp: bool = True,
    ambiguity_rtol: tuple[float, float, float] = (1e-5, 1e-4, 2e-6),
) -> ReferenceRender:
    """Render densely in float64.

    Args:
      gaussians: anything with ``means [N,3]``, ``log_scales [N]``, ``logit_opacities [N]``, ``rgb [N,3]``,
        ``active [N]`` (a :class:`gsjax.gaussians.Gaussians`, possibly holding float64 numpy arrays).
      w2c: [4, 4] world-to-camera.
      intrinsics: anything with ``fx, fy, cx, cy, height, width``.
      near: cull Gaussians with camera z <= near (m).
      max_contributors: if given, a pixel's walk also ends after this many contributors (the truncated
        semantics: the first K contributors in depth order).
      jacobian_clamp: False evaluates the EWA Jacobian at the true x/z, y/z (only used to show that a scene
        exercises the clamp).
      ambiguity_rtol: a pixel is flagged ``ambiguous`` when an alpha lies within relative distance
        ``ambiguity_rtol[0]`` of 1/255, a ``T (1 - alpha)`` within ``[1]`` of 1e-4, or two successive
        contributors' depths within ``[2]`` of each other: decisions that float32 arithmetic (about 6e-8
        relative per operation, compounded over the walk) may take the other way.
    """
    p = project(gaussians, w2c, intrinsics, near, jacobian_clamp)
    height, width = int(intrinsics.height), int(intrinsics.width)
    n = p.z.shape[0]
    rows, cols = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")

    order = np.flatnonzero(p.visible)
    order = order[np.argsort(p.z[order], kind="stable")]

    trans = np.ones((height, width))
    color = np.zeros((height, width, 3))
    silhouette = np.zeros((height, width))
    depth = np.zeros((height, width))
    depth_sq = np.zeros((height, width))
    done = np.zeros((height, width), bool)
    stopped = np.zeros((height, width), bool)
    cut = np.zeros((height, width), bool)
    ambiguous = np.zeros((height, width), bool)
    count = np.zeros((height, width), np.int64)
    contributors = np.zeros((height, width, n), bool)
    clamped = np.zeros((height, width, n), bool)
    candidates = np.zeros((height, width, n), bool)
    last_z = np.full((height, width), -np.inf)

    for k in order:
        dx, dy = cols - p.uv[k, 0], rows - p.uv[k, 1]
        a, b, c = p.conic[k, 0, 0], p.conic[k, 0, 1], p.conic[k, 1, 1]
        raw = p.opacity[k] * np.exp(-0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy))
        alpha = np.minimum(ALPHA_MAX, raw)
        cand = alpha >= ALPHA_MIN
        candidates[:, :, k] = cand
        live = cand & ~done
        new_t = trans * (1.0 - alpha)
        stop = live & (new_t < T_STOP)
        ambiguous |= ~done & (np.abs(alpha - ALPHA_MIN) <= ambiguity_rtol[0] * ALPHA_MIN)
        ambiguous |= live & (np.abs(new_t - T_STOP) <= ambiguity_rtol[1] * T_STOP)
        ambiguous |= live & (p.z[k] - last_z <= ambiguity_rtol[2] * p.z[k])
        add = live & ~stop
        if max_contributors is not None:
            over = add & (count >= max_contributors)
            cut |= over
            done |= over
            add &= ~over
        w = np.where(add, alpha * trans, 0.0)
        color += w[..., None] * p.rgb[k]
        silhouette += w
        depth += w * p.z[k]
        depth_sq += w * p.z[k] ** 2
        trans = np.where(add, new_t, trans)
        contributors[:, :, k] = add
        clamped[:, :, k] = add & (raw > ALPHA_MAX)
        count += add
        last_z = np.where(add, p.z[k], last_z)
        stopped |= stop
        done |= stop

    return ReferenceRender(
        color=color,
        depth=depth,
        silhouette=silhouette,
        depth_sq=depth_sq,
        transmittance=trans,
        contributors=contributors,
        clamped=clamped,
        candidates=candidates,
        count=count,
        num_candidates=candidates.sum(-1),
        stopped=stopped,
        cut=cut,
        ambiguous=ambiguous,
        projected=p,
        order=order,
    )


def tile_candidate_counts(ref: ReferenceRender, tile_size: int) -> np.ndarray:
    """[tiles_y, tiles_x] number of Gaussians that are candidates (alpha >= 1/255) at some pixel of each tile.

    A lower bound on the candidate list a tile-based rasterizer must hold for that tile.
    """
    height, width, n = ref.candidates.shape
    ty, tx = -(-height // tile_size), -(-width // tile_size)
    padded = np.zeros((ty * tile_size, tx * tile_size, n), bool)
    padded[:height, :width] = ref.candidates
    tiles = padded.reshape(ty, tile_size, tx, tile_size, n).any(axis=(1, 3))
    return tiles.sum(-1)


def expected_truncation(gaussians, w2c, intrinsics, max_contributors: int, near: float = 0.2) -> dict:
    """What a renderer with K = ``max_contributors`` slots per pixel must / may report.

    ``must``: pixels whose untruncated walk adds more than K Gaussians (the truncation changes the image).
    ``may``: pixels with more than K candidates at all (a renderer that cannot see past slot K may flag them).
    ``residual_must`` / ``residual_may``: the largest transmittance left after K contributors over those pixels.
    """
    full = render_reference(gaussians, w2c, intrinsics, near)
    cut = render_reference(gaussians, w2c, intrinsics, near, max_contributors=max_contributors)
    must = full.count > max_contributors
    may = full.num_candidates > max_contributors
    residual = cut.transmittance
    return dict(
        full=full,
        truncated=cut,
        must=int(must.sum()),
        may=int(may.sum()),
        residual_must=float(residual[must].max()) if must.any() else 0.0,
        residual_may=float(residual[may].max()) if may.any() else 0.0,
    )


def composite_reference(gaussians, w2c, intrinsics, contributors: np.ndarray, order: np.ndarray,
                        near: float = 0.2) -> ReferenceRender:
    """Blend a fixed contributor set at pose ``w2c`` (float64): every pixel's ``contributors`` [H, W, N] (chosen
    elsewhere, e.g. :func:`render_reference`'s at another pose), front to back in ``order`` (slot indices), with
    the alphas, centres and depths of ``w2c`` and no threshold or stop rule: what compositing a stale selection
    means. Only the images and ``transmittance`` are filled in."""
    p = project(gaussians, w2c, intrinsics, near)
    height, width = int(intrinsics.height), int(intrinsics.width)
    rows, cols = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    trans = np.ones((height, width))
    color, silhouette = np.zeros((height, width, 3)), np.zeros((height, width))
    depth, depth_sq = np.zeros((height, width)), np.zeros((height, width))
    for k in order:
        dx, dy = cols - p.uv[k, 0], rows - p.uv[k, 1]
        a, b, c = p.conic[k, 0, 0], p.conic[k, 0, 1], p.conic[k, 1, 1]
        alpha = np.minimum(ALPHA_MAX, p.opacity[k] * np.exp(-0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy)))
        w = np.where(contributors[:, :, k], alpha * trans, 0.0)
        color += w[..., None] * p.rgb[k]
        silhouette += w
        depth += w * p.z[k]
        depth_sq += w * p.z[k] ** 2
        trans = np.where(contributors[:, :, k], trans * (1.0 - alpha), trans)
    empty = np.zeros((height, width, 0), bool)
    return ReferenceRender(color=color, depth=depth, silhouette=silhouette, depth_sq=depth_sq, transmittance=trans,
                           contributors=contributors, clamped=empty, candidates=empty, count=contributors.sum(-1),
                           num_candidates=np.zeros((height, width), np.int64), stopped=np.zeros((height, width), bool),
                           cut=np.zeros((height, width), bool), ambiguous=np.zeros((height, width), bool),
                           projected=p, order=order)
