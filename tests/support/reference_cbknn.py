"""Dense float64 reference of CB-KNN (method_spec D.4-D.7, DESIGN 2.2.1): the definition of correctness for
``gsjax.raster.render(..., cbknn=...)``.

Written from the contract (the module and class docstrings of ``gsjax.raster.cbknn`` and the spec), independently
of the implementation. It is built on the canonical reference walk of ``reference_render.py``: that walk says which
Gaussians contribute to each pixel, in depth order (with the 0.99 clamp, the 1/255 threshold and the
``T (1 - alpha) < 1e-4`` stop). Everything below is per pixel p, vectorised over an [H, W, L] table of each pixel's
contributor list (L = the longest list).

* K_p: an explicit K (int or [H, W]) or the adaptive map (D.7): ``cnt[cell]`` = number of visible Gaussians (active,
  z > near, opacity >= 1/255, footprint on screen) whose centre u (px) lies in the cell, pixel j covering
  u in [j - 0.5, j + 0.5); ``rho = cnt / mean(cnt over non-empty cells)``;
  ``K = clip(round(k0 max(0.5, 1 + beta gamma / (rho + eps))), k_min, k_max)`` (round half to even).
* G_p: the first K_p contributors (``first_k``) or the K_p with the largest canonical blend weight f_i T_i, kept in
  depth order (``top_weight``); all contributors when there are fewer than K_p.
* ``C_p = mean_{G_p} u_k``; unit: ``u'_k = u_k + alpha (C_p - u_k) / (|C_p - u_k| + eps)``; fraction:
  ``u'_k = u_k + alpha (C_p - u_k)``; ``position=False``: ``u'_k = u_k``.
* ``f_k = min(0.99, o_k g_k(p; u_k))``, ``f'_k`` the same at u'_k with the same 2D covariance (no 1/255 threshold
  on f': a slot of G_p stays in G_p); depth z_k kept.
* colour: ``c_bar = sum_{G_p} f_k c_k / sum_{G_p} f_k`` for every slot of G_p (``colour=False``: c_k).
* hybrid: composite the whole canonical contributor list in depth order, (f'_k, c'_k) on G_p and (f_i, c_i)
  elsewhere, standard front-to-back transmittance; ``truncate=True``: only G_p. Background 0.

For finite differences the unit direction can be given from outside (``direction=``): the implementation puts a
stop_gradient on it, so its derivative is that of the shift with the direction held fixed.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.spatial.transform

from tests.support import reference_render as rr

# a unit direction computed from |C_p - u_k| below this (px) is float32 noise in a float32 renderer
DIRECTION_MIN_PX = 1e-2
# top_weight: the K-th and (K+1)-th canonical blend weights closer than this (relative) are a float32 tie
WEIGHT_TIE_RTOL = 1e-4
# adaptive K: a centre closer than this (px) to a cell / image border, or K0 (...) closer than this to a half
# integer, makes the K map depend on float32 rounding
CELL_MARGIN_PX = 1e-3
ROUND_MARGIN = 1e-4


def motion_from_poses_reference(w2c_prev2, w2c_prev1, tau_t: float = 0.05, tau_r: float = 5.0) -> float:
    """gamma = clip(max(|c1 - c2| / tau_t, angle(R1 R2^T) [deg] / tau_r), 0, 1), camera centres c = -R^T t."""
    a, b = np.asarray(w2c_prev2, np.float64), np.asarray(w2c_prev1, np.float64)
    c2, c1 = -a[:3, :3].T @ a[:3, 3], -b[:3, :3].T @ b[:3, 3]
    relative = b[:3, :3] @ a[:3, :3].T
    angle_deg = np.degrees(scipy.spatial.transform.Rotation.from_matrix(relative).magnitude())
    return float(np.clip(max(np.linalg.norm(c1 - c2) / tau_t, angle_deg / tau_r), 0.0, 1.0))


@dataclasses.dataclass
class KernelMap:
    """Adaptive K (D.7) of one view."""

    counts: np.ndarray  # [cells_y, cells_x] int: visible centres per cell
    rho: np.ndarray  # [cells_y, cells_x] float64
    raw: np.ndarray  # [cells_y, cells_x] k0 max(0.5, 1 + beta gamma / (rho + eps)) before rounding
    k: np.ndarray  # [cells_y, cells_x] int
    ambiguous: list[str]  # reasons the map may depend on float32 rounding (empty: it does not)


def kernel_map(
    projected: rr.Projected,
    candidates: np.ndarray,
    height: int,
    width: int,
    *,
    k0: float,
    beta: float,
    motion: float,
    eps: float = 1e-6,
    k_min: int = 2,
    k_max: int = 16,
    cell: int = 8,
) -> KernelMap:
    """Per-cell density and kernel size from the projection of the canonical render (D.7).

    With no non-empty cell the mean is undefined; we take rho = 0 everywhere (so K = k_max where beta gamma > 0).
    """
    p = projected
    u, v = p.uv[:, 0], p.uv[:, 1]
    counted = p.visible & (p.opacity >= rr.ALPHA_MIN)
    in_image = (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)
    counted = counted & in_image
    ambiguous = []
    on_screen = candidates.any(axis=(0, 1))  # a pixel with alpha >= 1/255 exists
    if np.any(counted & ~on_screen):
        ambiguous.append("a counted centre lies in the image but no pixel has alpha >= 1/255")
    cols = np.floor(u[counted] + 0.5).astype(int)
    rows = np.floor(v[counted] + 0.5).astype(int)
    cells_y, cells_x = -(-height // cell), -(-width // cell)
    counts = np.zeros((cells_y, cells_x), np.int64)
    np.add.at(counts, (rows // cell, cols // cell), 1)

    # centres within CELL_MARGIN_PX of a cell border (including the image border) may be binned either way
    near = p.visible & (p.opacity >= rr.ALPHA_MIN)
    for coord, size in ((u[near] + 0.5, width), (v[near] + 0.5, height)):
        borders = np.append(np.arange(0, size, cell), size)
        if np.any(np.abs(coord[:, None] - borders[None, :]).min(axis=1) < CELL_MARGIN_PX):
            ambiguous.append("a centre lies on a cell border")

    nonempty = counts > 0
    mean = counts[nonempty].mean() if nonempty.any() else 1.0
    rho = counts / mean
    raw = k0 * np.maximum(0.5, 1.0 + beta * motion / (rho + eps))
    k = np.clip(np.round(raw), k_min, k_max).astype(np.int64)
    frac = raw - np.floor(raw)
    at_half = (np.abs(frac - 0.5) < ROUND_MARGIN * np.maximum(raw, 1.0)) & (raw > k_min - 0.5) & (raw < k_max + 0.5)
    if at_half.any():
        ambiguous.append(f"K0 (...) within {ROUND_MARGIN} of a half integer in {int(at_half.sum())} cells")
    return KernelMap(counts=counts, rho=rho, raw=raw, k=k, ambiguous=ambiguous)


@dataclasses.dataclass
class CBKNNReference:
    """Images [H, W(, 3)] of the CB-KNN render, the per-pixel selection, and the diagnostics (float64)."""

    color: np.ndarray
    depth: np.ndarray
    silhouette: np.ndarray
    depth_sq: np.ndarray
    k_pixel: np.ndarray  # [H, W] int: K_p
    kernel: KernelMap | None  # the adaptive map, or None when K was given
    ids: np.ndarray  # [H, W, L] Gaussian slot of the l-th contributor (depth order), -1 past the end
    in_group: np.ndarray  # [H, W, L] bool: the contributor is in G_p
    centroid: np.ndarray  # [H, W, 2] C_p (px); 0 where G_p is empty
    direction: np.ndarray  # [H, W, L, 2] the unit direction (C_p - u_k) / (|C_p - u_k| + eps), 0 outside G_p
    centroid_distance: np.ndarray  # [H, W, L] |C_p - u_k| (px), 0 outside G_p
    alpha_canonical: np.ndarray  # [H, W, L] f at the canonical centre
    alpha_shifted: np.ndarray  # [H, W, L] f' (= f outside G_p)
    shift_px: np.ndarray  # [H, W, L] |u'_k - u_k|, 0 outside G_p
    mean_shift_px: float  # over all slots of all G_p
    fraction_fewer_than_k: float  # pixels whose canonical contributor count is below K_p
    ambiguous: np.ndarray  # [H, W] bool: a decision within float32 noise of its threshold
    canonical: rr.ReferenceRender

    def outputs(self) -> dict[str, np.ndarray]:
        return dict(color=self.color, depth=self.depth, silhouette=self.silhouette, depth_sq=self.depth_sq)

    def discrete_state(self) -> tuple[np.ndarray, ...]:
        """What must not change between theta - h, theta, theta + h for a finite difference to be valid."""
        return self.canonical.discrete_state() + (self.in_group, self.k_pixel)


def _alpha_at_pixels(projected: rr.Projected, ids: np.ndarray, centres: np.ndarray, height: int, width: int):
    """(min(0.99, o g), o g) of Gaussians ``ids`` [H, W, L] at their pixel, with centres [H, W, L, 2] (px)."""
    rows, cols = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    dx = cols[..., None] - centres[..., 0]
    dy = rows[..., None] - centres[..., 1]
    conic = projected.conic[ids]
    a, b, c = conic[..., 0, 0], conic[..., 0, 1], conic[..., 1, 1]
    raw = projected.opacity[ids] * np.exp(-0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy))
    return np.minimum(rr.ALPHA_MAX, raw), raw


def contributor_table(canonical: rr.ReferenceRender) -> np.ndarray:
    """[H, W, L] slot ids of each pixel's contributors in depth order (-1 past the end; L >= 1)."""
    height, width, _ = canonical.contributors.shape
    in_order = canonical.contributors[:, :, canonical.order]  # [H, W, V]
    length = max(1, int(canonical.count.max()))
    ids = np.full((height, width, length), -1, np.int64)
    rank = np.cumsum(in_order, axis=-1) - 1
    ii, jj, vv = np.nonzero(in_order)
    ids[ii, jj, rank[ii, jj, vv]] = canonical.order[vv]
    return ids


def render_cbknn_reference(
    gaussians,
    w2c,
    intrinsics,
    *,
    alpha: float = 0.2,
    k=None,
    k0: float = 5.0,
    beta: float = 0.3,
    motion: float = 0.0,
    eps: float = 1e-6,
    k_min: int = 2,
    k_max: int = 16,
    cell: int = 8,
    position: bool = True,
    colour: bool = True,
    truncate: bool = False,
    select: str = "first_k",
    shift_mode: str = "unit",
    near: float = 0.2,
    max_contributors: int | None = None,
    direction: np.ndarray | None = None,
    shifted_alpha_floor: float = 0.0,
) -> CBKNNReference:
    """CB-KNN render in float64.

    Args:
      gaussians, w2c, intrinsics, near, max_contributors: as :func:`reference_render.render_reference` (the
        canonical walk; ``max_contributors`` is the renderer's per-pixel slot count).
      k: None for the adaptive map from ``k0, beta, motion, eps, k_min, k_max, cell``; else an int or an [H, W]
        int array of K_p (k0, beta, motion, k_min, k_max, cell are then unused).
      direction: None, or an [H, W, L, 2] unit-direction table (from a previous call's ``.direction``) to use
        instead of the one computed here (unit mode only): finite differences of the stop-gradient direction.
      shifted_alpha_floor: a slot of G_p whose f' falls below this is dropped (f' = 0). 0 (the contract) keeps
        every slot; 1/255 is the alternative reading that re-applies the contributor threshold after the shift
        (only used to show that a test can tell the two apart).
      the rest: the CBKNN fields.
    """
    if select not in ("first_k", "top_weight") or shift_mode not in ("unit", "fraction"):
        raise ValueError(f"select {select!r} / shift_mode {shift_mode!r}")
    height, width = int(intrinsics.height), int(intrinsics.width)
    canonical = rr.render_reference(gaussians, w2c, intrinsics, near=near, max_contributors=max_contributors)
    p = canonical.projected

    kernel = None
    if k is None:
        kernel = kernel_map(
            p, canonical.candidates, height, width, k0=k0, beta=beta, motion=motion, eps=eps, k_min=k_min,
            k_max=k_max, cell=cell,
        )
        rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
        k_pixel = kernel.k[rows // cell, cols // cell]
    else:
        k_pixel = np.broadcast_to(np.asarray(k, np.int64), (height, width)).copy()

    ids = contributor_table(canonical)
    valid = ids >= 0
    safe = np.where(valid, ids, 0)
    length = ids.shape[-1]
    count = canonical.count
    uv = p.uv[safe]  # [H, W, L, 2]
    f, _ = _alpha_at_pixels(p, safe, uv, height, width)
    f = np.where(valid, f, 0.0)
    trans = np.cumprod(np.concatenate([np.ones((height, width, 1)), 1.0 - f[..., :-1]], axis=-1), axis=-1)
    weight = f * trans  # canonical blend weights
    ambiguous = canonical.ambiguous.copy()

    position_in_list = np.arange(length)
    if select == "first_k":
        in_group = valid & (position_in_list < k_pixel[..., None])
    else:
        ranked = np.argsort(np.where(valid, -weight, np.inf), axis=-1, kind="stable")
        rank = np.empty_like(ranked)
        np.put_along_axis(rank, ranked, np.broadcast_to(position_in_list, ranked.shape), axis=-1)
        in_group = valid & (rank < k_pixel[..., None])
        sorted_w = np.take_along_axis(np.where(valid, weight, -1.0), ranked, axis=-1)
        cut = count > k_pixel
        kk = np.minimum(k_pixel, length - 1)
        w_in = np.take_along_axis(sorted_w, np.maximum(kk - 1, 0)[..., None], axis=-1)[..., 0]
        w_out = np.take_along_axis(sorted_w, kk[..., None], axis=-1)[..., 0]
        ambiguous |= cut & (k_pixel > 0) & (w_in - w_out <= WEIGHT_TIE_RTOL * w_in)
    n_group = in_group.sum(-1)

    centroid = np.where(
        n_group[..., None] > 0,
        (uv * in_group[..., None]).sum(-2) / np.maximum(n_group, 1)[..., None],
        0.0,
    )
    to_centroid = np.where(in_group[..., None], centroid[..., None, :] - uv, 0.0)
    distance = np.linalg.norm(to_centroid, axis=-1)
    unit = to_centroid / (distance[..., None] + eps)
    if direction is not None:
        assert direction.shape == unit.shape, f"direction table {direction.shape}, expected {unit.shape}"
        unit = np.where(in_group[..., None], direction, 0.0)
    if shift_mode == "unit":
        step = alpha * unit
        ambiguous |= (in_group & (n_group[..., None] >= 2) & (distance < DIRECTION_MIN_PX)).any(-1)
    else:
        step = alpha * to_centroid
    if not position:
        step = np.zeros_like(step)
    shifted_uv = uv + np.where(in_group[..., None], step, 0.0)
    f_shifted, _ = _alpha_at_pixels(p, safe, shifted_uv, height, width)
    f_shifted = np.where(f_shifted < shifted_alpha_floor, 0.0, f_shifted)
    f_shifted = np.where(in_group, f_shifted, f)
    shift_px = np.linalg.norm(shifted_uv - uv, axis=-1)

    rgb = p.rgb[safe]  # [H, W, L, 3]
    if colour:
        f_group = f * in_group
        consensus = (f_group[..., None] * rgb).sum(-2) / np.where(n_group > 0, f_group.sum(-1), 1.0)[..., None]
        rgb = np.where(in_group[..., None], consensus[..., None, :], rgb)

    z = p.z[safe]
    t = np.ones((height, width))
    color = np.zeros((height, width, 3))
    depth = np.zeros((height, width))
    silhouette = np.zeros((height, width))
    depth_sq = np.zeros((height, width))
    for slot in range(length):
        used = in_group[..., slot] if truncate else valid[..., slot]
        a = np.where(used, f_shifted[..., slot], 0.0)
        w = a * t
        color += w[..., None] * rgb[..., slot, :]
        depth += w * z[..., slot]
        silhouette += w
        depth_sq += w * z[..., slot] ** 2
        t = t * (1.0 - a)

    total_slots = int(in_group.sum())
    return CBKNNReference(
        color=color,
        depth=depth,
        silhouette=silhouette,
        depth_sq=depth_sq,
        k_pixel=k_pixel,
        kernel=kernel,
        ids=ids,
        in_group=in_group,
        centroid=centroid,
        direction=np.where(in_group[..., None], unit, 0.0),
        centroid_distance=distance,
        alpha_canonical=f,
        alpha_shifted=f_shifted,
        shift_px=np.where(in_group, shift_px, 0.0),
        mean_shift_px=float(shift_px[in_group].sum() / total_slots) if total_slots else 0.0,
        fraction_fewer_than_k=float(np.mean(count < k_pixel)),
        ambiguous=ambiguous,
        canonical=canonical,
    )
