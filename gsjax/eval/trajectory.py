"""Trajectory metrics: ATE (two variants), RPE, timestamp association. numpy float64, run at the edges.

Inputs are **camera-to-world** poses ``c2w [N, 4, 4]`` (metres), as in TUM trajectory files and evo; gsjax's
internal world-to-camera poses are inverted by the caller. Two absolute-trajectory errors are provided because
the literature uses both under the same name ("ATE RMSE", method_spec B.1-B.2):

* :func:`ate_rmse_c2w`: the true RMSE of **camera centres** after Horn/Umeyama alignment of the estimate onto
  the ground truth (rigid, or similarity with ``with_scale``). This is what ``evo_ape tum gt est --align``
  reports and what the CB-KNN authors' final evaluation prints.
* :func:`ate_splatam_mean_w2c`: SplaTAM's number: the **mean** (not RMS) distance between the translation
  columns of the **world-to-camera** matrices after rigid Horn alignment. Compare with SplaTAM's published
  tables only through this one.

Ground-truth poses that are not finite, or that a ``valid`` mask excludes, are skipped and counted; a
non-finite *estimated* pose at a frame with valid ground truth is an error (a diverged run must not be scored
on its surviving frames).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from gsjax.camera import rotation_angle_np, se3_inverse_np
from gsjax.eval.association import associate_timestamps
from gsjax.eval.run_metrics import TrajectoryMetrics

if TYPE_CHECKING:
    import numpy.typing as npt

# Fewest frames for which a 3D rigid alignment is determined (non-collinear points).
MIN_FRAMES = 3


@dataclasses.dataclass(frozen=True)
class Alignment:
    """Similarity transform ``x -> scale * rotation @ x + translation`` (float64; metres).

    Attributes:
      rotation: [3, 3] float64 rotation.
      translation: [3] float64 translation (m).
      scale: the scale factor (1 for a rigid alignment).
    """

    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]
    scale: float = 1.0

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        """Apply the transform to points.

        Args:
          points: [..., 3] points (m).

        Returns:
          [..., 3] float64 transformed points (m).
        """
        return self.scale * np.asarray(points, np.float64) @ self.rotation.T + self.translation

    def apply_c2w(self, c2w: np.ndarray) -> np.ndarray:
        """Express camera-to-world poses in the aligned world: ``R_i -> R R_i``, centres mapped as points (the
        scale acts on positions only, so the result stays a rigid transform).

        Args:
          c2w: [..., 4, 4] camera-to-world poses (m).

        Returns:
          [..., 4, 4] float64 camera-to-world poses in the aligned world (a copy).
        """
        out = np.array(c2w, np.float64, copy=True)
        out[..., :3, :3] = self.rotation @ out[..., :3, :3]
        out[..., :3, 3] = self.apply_points(out[..., :3, 3])
        return out

    def to_json(self) -> dict:
        """The transform for ``metrics.json``.

        Returns:
          A dict: "rotation" (3 lists of 3 floats), "translation_m" (3 floats, m), "scale" (a float).
        """
        return {
            "rotation": self.rotation.tolist(),
            "translation_m": self.translation.tolist(),
            "scale": float(self.scale),
        }


class AteResult(NamedTuple):
    """An absolute trajectory error.

    Attributes:
      value_m: the statistic (RMSE for :func:`ate_rmse_c2w`, mean for :func:`ate_splatam_mean_w2c`), metres.
      errors_m: [n_used] float64 per-frame distances after alignment (m), in frame order.
      alignment: the transform applied to the estimate's positions.
      used: [N] bool, frames that entered the metric.
    """

    value_m: float
    errors_m: np.ndarray
    alignment: Alignment
    used: np.ndarray


class RpeResult(NamedTuple):
    """Relative pose errors between consecutive frames (pairs (i, i+1) with both frames valid).

    Attributes:
      trans_errors_m: [P] float64 translation error of each pair's relative motion (m).
      rot_errors_deg: [P] float64 rotation angle of each pair's relative-motion error (deg).
      pairs: [P, 2] int frame indices (i, i+1).
    """

    trans_errors_m: np.ndarray
    rot_errors_deg: np.ndarray
    pairs: np.ndarray

    @property
    def trans_rmse_m(self) -> float:
        """RMSE of the translation errors (m); NaN without a pair."""
        return _rmse(self.trans_errors_m)

    @property
    def trans_mean_m(self) -> float:
        """Mean of the translation errors (m); NaN without a pair."""
        return _mean(self.trans_errors_m)

    @property
    def rot_rmse_deg(self) -> float:
        """RMSE of the rotation errors (deg); NaN without a pair."""
        return _rmse(self.rot_errors_deg)

    @property
    def rot_mean_deg(self) -> float:
        """Mean of the rotation errors (deg); NaN without a pair."""
        return _mean(self.rot_errors_deg)


def _rmse(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if x.size else float("nan")


# ---------------------------------------------------------------------------------------------- geometry


def umeyama_alignment(source: np.ndarray, target: np.ndarray, with_scale: bool = False) -> Alignment:
    """Least-squares similarity (or rigid) transform mapping ``source`` [n, 3] onto ``target`` [n, 3].

    Minimises ``sum_i |target_i - (s R source_i + t)|^2`` (Umeyama, PAMI 1991, eqs. 34-43; for ``s = 1`` this is
    Horn's closed form): SVD of the cross-covariance with the reflection fix ``det(R) = +1``.

    Args:
      source: [n, 3] points to move (m).
      target: [n, 3] points to move them onto, row i matching row i of ``source`` (m).
      with_scale: estimate the scale s too (similarity); False: s = 1 (rigid).

    Returns:
      The float64 transform mapping ``source`` onto ``target``.

    Raises:
      ValueError: the shapes are not both [n, 3], or all source points coincide (``with_scale``).
    """
    source = np.asarray(source, np.float64)
    target = np.asarray(target, np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise ValueError(f"source and target must both have shape [n, 3], got {source.shape} and {target.shape}")
    mean_s, mean_t = source.mean(axis=0), target.mean(axis=0)
    xs, xt = source - mean_s, target - mean_t
    cov = xt.T @ xs / source.shape[0]
    u, d, vt = np.linalg.svd(cov)
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2] = -1.0
    rotation = (u * sign) @ vt
    scale = 1.0
    if with_scale:
        var_s = np.mean(np.sum(xs * xs, axis=1))
        if not var_s > 0:
            raise ValueError("cannot estimate a scale: all source points coincide")
        scale = float(np.sum(d * sign) / var_s)
    return Alignment(rotation=rotation, translation=mean_t - scale * rotation @ mean_s, scale=scale)


# ------------------------------------------------------------------------------------------- validity


def _as_poses(c2w: npt.ArrayLike, name: str) -> np.ndarray:
    poses = np.asarray(c2w, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape [N, 4, 4], got {list(poses.shape)}")
    return poses


def _frames_used(est_c2w, gt_c2w, valid) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(est, gt, used): float64 poses and the mask of frames with finite, valid GT; checks the estimate there."""
    est = _as_poses(est_c2w, "est_c2w")
    gt = _as_poses(gt_c2w, "gt_c2w")
    if est.shape != gt.shape:
        raise ValueError(f"est_c2w and gt_c2w must have the same number of frames, got {len(est)} and {len(gt)}")
    used = np.isfinite(gt).all(axis=(1, 2))
    if valid is not None:
        valid = np.asarray(valid, bool)
        if valid.shape != used.shape:
            raise ValueError(f"valid must have shape [{len(gt)}], got {list(valid.shape)}")
        used &= valid
    bad_est = used & ~np.isfinite(est).all(axis=(1, 2))
    if bad_est.any():
        raise ValueError(
            f"the estimated trajectory has {int(bad_est.sum())} non-finite pose(s) at frames with valid ground truth,"
            f" first at frame {int(np.argmax(bad_est))}"
        )
    if used.sum() < MIN_FRAMES:
        raise ValueError(f"need at least {MIN_FRAMES} frames with valid ground truth, got {int(used.sum())}")
    return est, gt, used


# ----------------------------------------------------------------------------------------------- metrics


def ate_rmse_c2w(
    est_c2w: npt.ArrayLike, gt_c2w: npt.ArrayLike, valid: npt.ArrayLike | None = None, with_scale: bool = False
) -> AteResult:
    """ATE as evo reports it: RMSE (m) of camera centres after aligning the estimate onto the ground truth.

    Args:
      est_c2w: [N, 4, 4] estimated camera-to-world poses (m), frame i matching frame i of ``gt_c2w``.
      gt_c2w: [N, 4, 4] ground-truth camera-to-world poses (m).
      valid: optional [N] bool; frames with False, or with non-finite GT, are skipped.
      with_scale: similarity (Umeyama) instead of rigid (Horn) alignment, for scale-free estimates.

    Returns:
      The RMSE (m), per-frame errors, alignment and frames used.

    Raises:
      ValueError: a shape is wrong, an estimated pose is not finite where the GT is valid, or fewer than 3 frames
        have valid GT.
    """
    est, gt, used = _frames_used(est_c2w, gt_c2w, valid)
    est_c, gt_c = est[used, :3, 3], gt[used, :3, 3]
    alignment = umeyama_alignment(est_c, gt_c, with_scale=with_scale)
    errors = np.linalg.norm(alignment.apply_points(est_c) - gt_c, axis=1)
    return AteResult(_rmse(errors), errors, alignment, used)


def ate_so_far(est_c2w: np.ndarray, gt_c2w: npt.ArrayLike, gt_valid: npt.ArrayLike) -> float | None:
    """ATE RMSE (m) of the first ``len(est_c2w)`` frames against ``gt_c2w`` [>= n, 4, 4] where ``gt_valid``, or
    None while fewer than ``MIN_FRAMES`` of them have ground truth (a run in progress)."""
    n = len(est_c2w)
    try:
        return ate_rmse_c2w(est_c2w, np.asarray(gt_c2w)[:n], np.asarray(gt_valid)[:n]).value_m
    except ValueError:
        return None


def ground_truth_on_estimate(est_c2w: npt.ArrayLike, gt_c2w: npt.ArrayLike,
                             valid: npt.ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The ground truth drawn in the estimate's world frame, for display: (the frames with ground truth and a finite
    estimate [n] int, their GT poses [n, 4, 4]), or None when there is no such frame.

    The GT is moved rigidly so that its pose at the first such frame is the estimate's: both trajectories start
    together and drift apart as they do, orientations included. (The ATE's alignment of camera centres would
    leave the rotation about a straight path undetermined.) Arguments as :func:`ate_rmse_c2w`.
    """
    est, gt = _as_poses(est_c2w, "est_c2w"), _as_poses(gt_c2w, "gt_c2w")
    used = np.isfinite(gt).all(axis=(1, 2)) & np.isfinite(est).all(axis=(1, 2))
    if valid is not None:
        used &= np.asarray(valid, bool)
    frames = np.flatnonzero(used)
    if not len(frames):
        return None
    first = frames[0]
    return frames, est[first] @ se3_inverse_np(gt[first]) @ gt[frames]


class Drift(NamedTuple):
    """The camera error without alignment, per frame with ground truth: ``frames`` [n] (estimate rows),
    ``error_m`` [n] distance between camera centres (m), ``error_deg`` [n] angle between orientations (deg), after
    the ground truth is started at the estimate's first pose (:func:`ground_truth_on_estimate`)."""

    frames: np.ndarray
    error_m: np.ndarray
    error_deg: np.ndarray


def drift(est_c2w: npt.ArrayLike, gt_c2w: npt.ArrayLike, valid: npt.ArrayLike | None = None) -> Drift | None:
    """How far the estimate has drifted from the ground truth at each frame, where the error enters frame by frame
    (the ATE's alignment spreads it over the whole run); None without a frame to compare. Arguments as
    :func:`ate_rmse_c2w`."""
    on_estimate = ground_truth_on_estimate(est_c2w, gt_c2w, valid)
    if on_estimate is None:
        return None
    frames, gt = on_estimate
    est = _as_poses(est_c2w, "est_c2w")[frames]
    error_m = np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1)
    error_deg = np.degrees(rotation_angle_np(np.swapaxes(est[:, :3, :3], 1, 2) @ gt[:, :3, :3]))
    return Drift(frames, error_m, error_deg)


def ate_splatam_mean_w2c(est_c2w: npt.ArrayLike, gt_c2w: npt.ArrayLike,
                         valid: npt.ArrayLike | None = None) -> AteResult:
    """SplaTAM's "ATE RMSE" (method_spec B.1): the MEAN distance (m) between w2c translation columns after rigid
    Horn alignment. Not an RMSE and not camera centres; use it only to compare with SplaTAM's published numbers.

    w2c translations (``-R^T c``) depend on the choice of world frame, so, as SplaTAM's loader does for the GT
    and as its estimate is by construction, both trajectories are first re-expressed relative to their first
    used frame (``c2w_0^{-1} c2w_i``). SplaTAM aligns the GT onto the estimate; for a rigid alignment the residual
    distances are the same either way, and here (as in :func:`ate_rmse_c2w`) the estimate is aligned onto the GT.

    Args:
      est_c2w: [N, 4, 4] estimated camera-to-world poses (m), frame i matching frame i of ``gt_c2w``.
      gt_c2w: [N, 4, 4] ground-truth camera-to-world poses (m).
      valid: optional [N] bool; frames with False, or with non-finite GT, are skipped.

    Returns:
      The mean distance (m) as ``value_m``, per-frame errors, the rigid alignment (no scale: SplaTAM has none) and
        the frames used.

    Raises:
      ValueError: as :func:`ate_rmse_c2w`.
    """
    est, gt, used = _frames_used(est_c2w, gt_c2w, valid)
    est, gt = est[used], gt[used]
    est_t = se3_inverse_np(se3_inverse_np(est[0]) @ est)[:, :3, 3]
    gt_t = se3_inverse_np(se3_inverse_np(gt[0]) @ gt)[:, :3, 3]
    alignment = umeyama_alignment(est_t, gt_t, with_scale=False)
    errors = np.linalg.norm(alignment.apply_points(est_t) - gt_t, axis=1)
    return AteResult(_mean(errors), errors, alignment, used)


def rpe(est_c2w: npt.ArrayLike, gt_c2w: npt.ArrayLike, valid: npt.ArrayLike | None = None) -> RpeResult:
    """Relative pose error over consecutive frames (evo's RPE with delta = 1 frame).

    For each pair (i, i+1) where both frames are used, ``E = (Q_i^-1 Q_{i+1})^-1 (P_i^-1 P_{i+1})`` with Q the GT
    and P the estimate; the errors are ``|trans(E)|`` (m) and ``angle(E)`` (deg). Pairs spanning a skipped
    frame are left out (their motion is not one frame's). RPE does not depend on a rigid alignment; for a scale
    alignment, pass the aligned estimate (:meth:`Alignment.apply_c2w`).

    Args:
      est_c2w: [N, 4, 4] estimated camera-to-world poses (m), frame i matching frame i of ``gt_c2w``.
      gt_c2w: [N, 4, 4] ground-truth camera-to-world poses (m).
      valid: optional [N] bool; frames with False, or with non-finite GT, are skipped.

    Returns:
      The per-pair errors (m, deg) and the pairs.

    Raises:
      ValueError: as :func:`ate_rmse_c2w` (at least 3 used frames are needed, like ATE).
    """
    est, gt, used = _frames_used(est_c2w, gt_c2w, valid)
    i = np.flatnonzero(used[:-1] & used[1:])
    rel_gt = se3_inverse_np(gt[i]) @ gt[i + 1]
    rel_est = se3_inverse_np(est[i]) @ est[i + 1]
    err = se3_inverse_np(rel_gt) @ rel_est
    return RpeResult(
        trans_errors_m=np.linalg.norm(err[:, :3, 3], axis=1),
        rot_errors_deg=np.degrees(rotation_angle_np(err[:, :3, :3])),
        pairs=np.stack([i, i + 1], axis=1),
    )


# ---------------------------------------------------------------------------------------------- report

#: What each trajectory key means; written into ``evaluate_trajectory``'s result so a metrics file explains itself.
DEFINITIONS = {
    "ate_rmse_c2w": "RMSE of camera centres (c2w) after Horn/Umeyama alignment of the estimate onto the GT "
    "(evo_ape --align; with --scale also scale)",
    "ate_mean_c2w": "mean of the same per-frame camera-centre errors",
    "ate_splatam_mean_w2c": "SplaTAM's 'ATE RMSE': MEAN error of w2c translations after rigid Horn alignment, both "
    "trajectories relative to their first frame (always rigid)",
    "rpe": "relative pose error between consecutive evaluated frames (delta = 1 frame), translation and rotation",
}


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def evaluate_trajectory(
    est_timestamps: npt.ArrayLike,
    est_c2w: npt.ArrayLike,
    gt_timestamps: npt.ArrayLike,
    gt_c2w: npt.ArrayLike,
    gt_valid: npt.ArrayLike | None = None,
    max_dt: float = 0.02,
    with_scale: bool = False,
) -> TrajectoryMetrics:
    """All trajectory metrics of an estimate against ground truth (JSON-friendly: ``dataclasses.asdict``).

    Poses are associated by timestamp (:func:`gsjax.eval.association.associate_timestamps`), GT poses that are
    not finite or have ``gt_valid`` False are skipped and counted, then ATE (both variants, see the module
    docstring) and RPE are computed on the remaining frames.

    Args:
      est_timestamps: [N] timestamps of the estimate (s).
      est_c2w: [N, 4, 4] estimated camera-to-world poses (m).
      gt_timestamps: [M] timestamps of the ground truth (s).
      gt_c2w: [M, 4, 4] ground-truth camera-to-world poses (m).
      gt_valid: optional [M] bool, which GT poses to use.
      max_dt: association tolerance (s).
      with_scale: similarity alignment for ``ate_*_c2w`` and RPE (the SplaTAM variant stays rigid).

    Returns:
      the metrics, a :class:`gsjax.eval.run_metrics.TrajectoryMetrics`: float metrics (units in the name: ``_m``,
        ``_cm``, ``_deg``; None where undefined), counts (``num_*``), the alignment, ``per_frame`` (the per-frame
        errors behind the statistics: ``est_index`` and ``ate_c2w_m`` of every evaluated estimate row;
        ``rpe_est_index``, the second row of each RPE pair, with ``rpe_trans_m`` and ``rpe_rot_deg``) and
        ``definitions``.

    Raises:
      ValueError: a shape is wrong, no estimated pose has a GT timestamp within ``max_dt``, or as
        :func:`ate_rmse_c2w` on the associated frames.
    """
    est_c2w = _as_poses(est_c2w, "est_c2w")
    gt_c2w = _as_poses(gt_c2w, "gt_c2w")
    for name, stamps, poses in (("est", est_timestamps, est_c2w), ("gt", gt_timestamps, gt_c2w)):
        if np.shape(stamps) != (len(poses),):
            raise ValueError(f"{name}_timestamps must have shape [{len(poses)}], got {list(np.shape(stamps))}")
    valid = np.isfinite(gt_c2w).all(axis=(1, 2))
    if gt_valid is not None:
        if np.shape(gt_valid) != (len(gt_c2w),):
            raise ValueError(f"gt_valid must have shape [{len(gt_c2w)}], got {list(np.shape(gt_valid))}")
        valid &= np.asarray(gt_valid, bool)
    est_idx, gt_idx = associate_timestamps(est_timestamps, gt_timestamps, max_dt)
    if len(est_idx) == 0:
        raise ValueError(f"no estimated pose has a ground-truth timestamp within max_dt = {max_dt} s")
    est, gt, used = est_c2w[est_idx], gt_c2w[gt_idx], valid[gt_idx]

    ate = ate_rmse_c2w(est, gt, used, with_scale=with_scale)
    ate_splatam = ate_splatam_mean_w2c(est, gt, used)
    rel = rpe(ate.alignment.apply_c2w(est), gt, used)
    return TrajectoryMetrics(
        ate_rmse_c2w_m=ate.value_m,
        ate_rmse_c2w_cm=100.0 * ate.value_m,
        ate_mean_c2w_m=_mean(ate.errors_m),
        ate_max_c2w_m=float(np.max(ate.errors_m)),
        ate_splatam_mean_w2c_m=ate_splatam.value_m,
        ate_splatam_mean_w2c_cm=100.0 * ate_splatam.value_m,
        rpe_trans_rmse_m=_finite_or_none(rel.trans_rmse_m),
        rpe_trans_mean_m=_finite_or_none(rel.trans_mean_m),
        rpe_rot_rmse_deg=_finite_or_none(rel.rot_rmse_deg),
        rpe_rot_mean_deg=_finite_or_none(rel.rot_mean_deg),
        num_est_poses=int(len(est_c2w)),
        num_gt_poses=int(len(gt_c2w)),
        num_associated=int(len(est_idx)),
        num_unassociated_est=int(len(est_c2w) - len(est_idx)),
        num_skipped_invalid_gt=int(np.sum(~used)),
        num_evaluated=int(np.sum(used)),
        num_rpe_pairs=int(len(rel.pairs)),
        max_dt_s=float(max_dt),
        with_scale=bool(with_scale),
        alignment=ate.alignment.to_json(),
        per_frame={
            "est_index": est_idx[ate.used].tolist(),
            "ate_c2w_m": ate.errors_m.tolist(),
            "rpe_est_index": est_idx[rel.pairs[:, 1]].tolist(),
            "rpe_trans_m": rel.trans_errors_m.tolist(),
            "rpe_rot_deg": rel.rot_errors_deg.tolist(),
        },
        definitions=dict(DEFINITIONS),
    )
