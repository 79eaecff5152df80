"""Timestamp association of an estimated trajectory with ground truth (numpy)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt


def associate_timestamps(
    est_timestamps: npt.ArrayLike, gt_timestamps: npt.ArrayLike, max_dt: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """Match every estimated timestamp to the nearest ground-truth timestamp within ``max_dt`` seconds.

    This is evo's nearest-time association when the estimate is the shorter (or equally long) trajectory, the
    usual case: each estimated pose is used at most once, ties go to the earlier GT stamp, and estimated poses
    without a GT stamp within ``max_dt`` are dropped. The GT stamps need not be sorted. A GT stamp may serve several
    estimated poses: GT is usually sampled faster than the frames, and a pose's error must not depend on which
    other poses exist. (The TUM reader uses this rule for its GT too; for pairing colour with depth images, each
    to be used once, it uses TUM associate.py's greedy one-to-one matching, :func:`gsjax.data.tum.associate`.)

    Args:
      est_timestamps: [N] seconds.
      gt_timestamps: [M] seconds.
      max_dt: largest accepted |t_est - t_gt| (s).

    Returns:
      (est_index [K], gt_index [K]) int arrays, increasing in est_index.
    """
    est_t = np.asarray(est_timestamps, np.float64)
    gt_t = np.asarray(gt_timestamps, np.float64)
    if est_t.ndim != 1 or gt_t.ndim != 1:
        raise ValueError(f"timestamps must be 1-D, got shapes {list(est_t.shape)} and {list(gt_t.shape)}")
    if not (np.isfinite(max_dt) and max_dt >= 0):
        raise ValueError(f"max_dt must be a finite number >= 0, got {max_dt!r}")
    if len(gt_t) == 0 or len(est_t) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order = np.argsort(gt_t, kind="stable")
    sorted_t = gt_t[order]
    upper = np.clip(np.searchsorted(sorted_t, est_t, side="left"), 0, len(sorted_t) - 1)
    lower = np.clip(upper - 1, 0, len(sorted_t) - 1)
    d_upper = np.abs(sorted_t[upper] - est_t)
    d_lower = np.abs(sorted_t[lower] - est_t)
    best = np.where(d_lower <= d_upper, lower, upper)
    keep = np.minimum(d_lower, d_upper) <= max_dt  # NaN stamps compare False and are dropped
    est_index = np.flatnonzero(keep)
    return est_index, order[best[keep]]
