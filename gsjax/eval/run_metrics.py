"""``metrics.json`` as one typed record: what a finished run measured.

The run's outputs build a :class:`RunMetrics` and write it with :meth:`RunMetrics.to_json`; the report, the sweep,
the viewer and the experiments read it back with :func:`read_run_metrics` (or :meth:`RunMetrics.from_json`).
The JSON keys are the field names, in field order. Runs made before a key existed read back with its default
(None, empty); keys a newer gsjax added are ignored.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any


@dataclasses.dataclass(frozen=True)
class TrajectoryMetrics:
    """:func:`gsjax.eval.trajectory.evaluate_trajectory`'s result: the estimate against the ground truth, camera
    centres of camera-to-world poses in the ground truth's frame after alignment (``_m``, ``_cm``, ``_deg``, ``_s``
    name the units; None where undefined).

    Attributes:
      ate_rmse_c2w_m: ATE, the RMSE of the camera centres after Horn/Umeyama alignment (evo_ape --align) (m).
      ate_rmse_c2w_cm: the same in cm: the ATE gsjax reports.
      ate_mean_c2w_m: the mean of the same per-frame camera-centre errors (m).
      ate_max_c2w_m: the largest of them (m).
      ate_splatam_mean_w2c_m: SplaTAM's "ATE RMSE": the mean error of world-to-camera translations after rigid
        alignment, both trajectories relative to their first frame (m).
      ate_splatam_mean_w2c_cm: the same in cm.
      rpe_trans_rmse_m: RPE between consecutive evaluated frames, translation, RMSE (m).
      rpe_trans_mean_m: the same, mean (m).
      rpe_rot_rmse_deg: RPE, rotation angle, RMSE (deg).
      rpe_rot_mean_deg: the same, mean (deg).
      num_est_poses: estimated poses given.
      num_gt_poses: ground-truth poses given.
      num_associated: estimated poses with a ground-truth stamp within ``max_dt_s``.
      num_unassociated_est: estimated poses without one.
      num_skipped_invalid_gt: associated poses left out because their ground truth is not finite or not rigid.
      num_evaluated: poses the ATE is computed on.
      num_rpe_pairs: consecutive pairs the RPE is computed on.
      max_dt_s: the association tolerance (s).
      with_scale: whether the alignment also fits a scale (the SplaTAM variant stays rigid).
      alignment: the alignment of the estimate onto the ground truth: ``rotation`` [3, 3], ``translation_m`` [3],
        ``scale``.
      per_frame: the errors behind the statistics: ``est_index`` and ``ate_c2w_m`` (m) per evaluated estimate row;
        ``rpe_est_index`` (the second row of each pair), ``rpe_trans_m`` (m) and ``rpe_rot_deg`` (deg) per RPE pair.
      definitions: each metric's definition in words, by name.
    """

    ate_rmse_c2w_m: float
    ate_rmse_c2w_cm: float
    ate_mean_c2w_m: float | None = None
    ate_max_c2w_m: float | None = None
    ate_splatam_mean_w2c_m: float | None = None
    ate_splatam_mean_w2c_cm: float | None = None
    rpe_trans_rmse_m: float | None = None
    rpe_trans_mean_m: float | None = None
    rpe_rot_rmse_deg: float | None = None
    rpe_rot_mean_deg: float | None = None
    num_est_poses: int | None = None
    num_gt_poses: int | None = None
    num_associated: int | None = None
    num_unassociated_est: int | None = None
    num_skipped_invalid_gt: int | None = None
    num_evaluated: int | None = None
    num_rpe_pairs: int | None = None
    max_dt_s: float | None = None
    with_scale: bool = False
    alignment: dict[str, Any] | None = None
    # est_index, ate_c2w_m (one per evaluated row); rpe_est_index, rpe_trans_m, rpe_rot_deg (one per RPE pair)
    per_frame: dict[str, list] | None = None
    definitions: dict[str, str] | None = None


@dataclasses.dataclass(frozen=True)
class RenderMetrics:
    """SplaTAM's rendering metrics on the evaluation frames (t = 0 and every ``eval_every``-th), the map rendered at
    the estimated poses at the end of the run.

    Attributes:
      frames: the evaluated frame numbers [n].
      mean: the means over those frames of ``psnr_db`` (dB), ``ssim``, ``ms_ssim``, ``ms_ssim_scales`` (the scales
        MS-SSIM could use at this size) and ``depth_l1_m`` (m), plus ``depth_l1_cm`` (cm); None when no frame was
        evaluated. ``depth_l1_*`` is None when no frame had usable depth.
      per_frame: [n] the same metrics per evaluated frame (without ``depth_l1_cm``).
    """

    frames: list[int] = dataclasses.field(default_factory=list)
    mean: dict[str, float] | None = None
    per_frame: list[dict[str, float]] = dataclasses.field(default_factory=list)

    def at(self, frame: int) -> dict[str, float] | None:
        """One evaluated frame's metrics.

        Args:
          frame: a frame number.

        Returns:
          Its dict of ``per_frame`` metrics, or None when it was not evaluated.
        """
        return self.per_frame[self.frames.index(frame)] if frame in self.frames[:len(self.per_frame)] else None


@dataclasses.dataclass(frozen=True)
class CBKNNSummary:
    """CB-KNN's parameters and its statistics on sample frames, for a run whose keyframe renders it smoothed.

    Attributes:
      mode: ``code_parity`` or ``paper`` (``cbknn.mode``).
      alpha: the shift strength (``cbknn.params.alpha``; px in ``shift_mode`` pixels).
      k0: the base number of neighbours (``cbknn.params.k0``).
      beta: the motion coupling (``cbknn.params.beta``).
      cell: the density grid's cell side (px).
      samples: per sample frame: ``frame``, ``gamma`` (the motion used), ``k_mean``, ``k_min``, ``k_max`` (the
        adaptive K over the pixels), ``rho_max`` (the largest density), ``empty_cells``, ``mean_shift_px`` (px)
        and ``fraction_fewer_than_k`` (pixels with fewer than K contributors).
    """

    mode: str
    alpha: float
    k0: float
    beta: float
    cell: int
    samples: list[dict[str, float]] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class CheckpointSummary:
    """The run's checkpoints.

    Attributes:
      count: checkpoints the run wrote (a resumed run counts those its earlier processes wrote).
      every_frames: ``--checkpoint-every`` (frames).
      mean_s: mean time to write one (s).
      max_s: the longest (s).
      last_bytes: the last one's size (bytes; a checkpoint writes what is new since the previous one).
      max_bytes: the largest one's size (bytes).
    """

    count: int
    every_frames: int
    mean_s: float
    max_s: float
    last_bytes: int
    max_bytes: int


@dataclasses.dataclass(frozen=True, kw_only=True)
class RunMetrics:
    """Everything ``metrics.json`` holds.

    Attributes:
      dataset: the dataset's name (``tum``, ``7scenes``, ``rosbag``, ...).
      frames: frames processed.
      width: the working width (px).
      height: the working height (px).
      trajectory: the trajectory errors, or None without ground truth (fewer than 3 valid poses).
      constant_pose_ate_rmse_c2w_cm: the ATE of a camera that never moves, a baseline (cm), or None.
      render: rendering metrics on the evaluation frames.
      cbknn: CB-KNN's diagnostics, or None when it did not smooth renders.
      frames_per_s: SLAM throughput, compilation included (frames/s), or None.
      seconds_per_frame: its inverse (s), or None.
      stage_timings_s: seconds per stage: ``read_frames_s``, ``slam_s``, ``checkpoint_s``, ``regrow_s``,
        ``compile_s_estimate``, ``outputs_s``, ``report_s`` (and ``observe_s`` with the viewer) (s).
      num_gaussians: the final map's active Gaussians.
      capacity: the map's slots (Gaussians it can hold).
      keyframes: keyframes stored at the end.
      nonfinite_tracking_iterations: tracking iterations skipped because the loss or gradient was not finite.
      nonfinite_mapping_iterations: the same for mapping.
      frames_with_truncated_render: frames whose densification render was truncated by the rasterizer's
        capacities.
      max_truncation_residual: the largest transmittance truncation left in such a render, or None.
      skipped_frames: frames with too little valid depth, which kept their predicted pose.
      retried_frames: frames whose tracking diverged and was tracked again.
      diverged_frames: frames that fell back to the constant-velocity prediction.
      nonfinite_gaussians: Gaussians freed because a parameter was not finite.
      checkpoints: the checkpoints written, or None.
      warnings: every warning of the run, one line each.
      camera: the intrinsics at the working resolution (``fx``, ``fy``, ``cx``, ``cy`` px; ``width``, ``height``)
        and ``depth_scale`` (stored depth units per metre; None where the dataset gives metres).
      config: the SLAM config as a dict (``config.json`` holds it with the run's input).
      world_from_map: [4, 4] (nested lists) the transform from map coordinates (the first camera's frame,
        ``map.ply``'s) to the trajectory file's frame (m).
      keyframe_frames: the frame numbers stored as keyframes, in order.
      per_frame: one list per series, a value per frame (None where not finite): ``tracking_loss``,
        ``mapping_loss``, ``num_gaussians``, ``added``, ``dropped``, ``gamma``, ``tracking_iters``, ``depth_valid``
        (:class:`gsjax.slam.system.StepOutputs` defines each).
    """

    dataset: str | None = None
    frames: int
    width: int | None = None
    height: int | None = None
    trajectory: TrajectoryMetrics | None = None
    constant_pose_ate_rmse_c2w_cm: float | None = None
    render: RenderMetrics = dataclasses.field(default_factory=RenderMetrics)
    cbknn: CBKNNSummary | None = None
    frames_per_s: float | None = None
    seconds_per_frame: float | None = None
    stage_timings_s: dict[str, float] = dataclasses.field(default_factory=dict)
    num_gaussians: int | None = None
    capacity: int | None = None
    keyframes: int | None = None
    nonfinite_tracking_iterations: int = 0
    nonfinite_mapping_iterations: int = 0
    frames_with_truncated_render: int = 0
    max_truncation_residual: float | None = None
    skipped_frames: list[int] | None = None
    retried_frames: list[int] | None = None
    diverged_frames: list[int] | None = None
    nonfinite_gaussians: int = 0
    checkpoints: CheckpointSummary | None = None
    warnings: list[str] = dataclasses.field(default_factory=list)
    camera: dict[str, Any] | None = None
    config: dict[str, Any] | None = None
    world_from_map: list[list[float]] | None = None
    keyframe_frames: list[int] = dataclasses.field(default_factory=list)
    per_frame: dict[str, list] = dataclasses.field(default_factory=dict)

    @property
    def ate_cm(self) -> float | None:
        """ATE RMSE of the camera centres (cm), or None without ground truth."""
        return None if self.trajectory is None else self.trajectory.ate_rmse_c2w_cm

    @property
    def psnr_db(self) -> float | None:
        """Mean PSNR over the evaluation frames (dB), or None."""
        return None if self.render.mean is None else self.render.mean["psnr_db"]

    def to_json(self) -> dict[str, Any]:
        """The record as ``metrics.json`` holds it.

        Returns:
          A JSON-ready dict: the field names as keys, in field order, nested records as dicts.
        """
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, value: dict[str, Any]) -> RunMetrics:
        """The record of a ``metrics.json`` object.

        Args:
          value: the parsed JSON object; a key it lacks takes its default, a key the record does not know is ignored.

        Returns:
          The record, a :class:`RunMetrics`.

        Raises:
          ValueError: naming a key whose value has the wrong shape, or a required key that is missing.
        """
        return _record(cls, value)


def read_run_metrics(path: str | Path) -> RunMetrics:
    """Read a run's ``metrics.json``, of this gsjax or an older one.

    Args:
      path: the file.

    Returns:
      The record it holds, a :class:`RunMetrics`.

    Raises:
      ValueError: naming the file, when it cannot be read or is not a ``metrics.json``.
    """
    path = Path(path)
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: cannot be read as JSON ({error})") from None
    try:
        return RunMetrics.from_json(value)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


# The fields that hold a record of their own, per record type.
_NESTED: dict[type, dict[str, type]] = {
    RunMetrics: dict(trajectory=TrajectoryMetrics, render=RenderMetrics, cbknn=CBKNNSummary,
                     checkpoints=CheckpointSummary)}


def _record(cls: type, value: Any, key: str | None = None):
    """``cls`` from a JSON object; ``key``: where it sits in its parent, for the error message."""
    where = f"'{key}' " if key else ""
    if not isinstance(value, dict):
        raise ValueError(f"{where}expected a JSON object, got {type(value).__name__}")
    kwargs = {}
    for field in dataclasses.fields(cls):
        if field.name in value:
            item, nested = value[field.name], _NESTED.get(cls, {}).get(field.name)
            kwargs[field.name] = item if nested is None or item is None else _record(nested, item, field.name)
    missing = [f.name for f in dataclasses.fields(cls) if f.name not in kwargs
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise ValueError(f"{where}has no {', '.join(repr(name) for name in missing)}")
    return cls(**kwargs)
