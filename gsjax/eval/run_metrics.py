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
    """:func:`gsjax.eval.trajectory.evaluate_trajectory`'s result (see it for the definitions; ``_m``, ``_cm``,
    ``_deg`` name the units; None where undefined)."""

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
    """SplaTAM's rendering metrics on the evaluation frames: ``frames`` [n]; ``per_frame`` [n] dicts of
    ``psnr_db``, ``ssim``, ``ms_ssim``, ``ms_ssim_scales``, ``depth_l1_m``; ``mean`` their means plus
    ``depth_l1_cm`` (None when no frame had usable depth)."""

    frames: list[int] = dataclasses.field(default_factory=list)
    mean: dict[str, float] | None = None
    per_frame: list[dict[str, float]] = dataclasses.field(default_factory=list)

    def at(self, frame: int) -> dict[str, float] | None:
        """Frame ``frame``'s metrics, or None when it was not evaluated."""
        return self.per_frame[self.frames.index(frame)] if frame in self.frames[:len(self.per_frame)] else None


@dataclasses.dataclass(frozen=True)
class CBKNNSummary:
    """CB-KNN's parameters and, per sample frame, its statistics (``frame``, ``gamma``, ``k_mean``, ``k_min``,
    ``k_max``, ``rho_max``, ``empty_cells``, ``mean_shift_px``, ``fraction_fewer_than_k``), when it smoothed
    renders."""

    mode: str
    alpha: float
    k0: float
    beta: float
    cell: int
    samples: list[dict[str, float]] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class CheckpointSummary:
    """The run's checkpoints: how many, how often (frames), their mean and largest time (s) and size (bytes)."""

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
      dataset, frames, width, height: the input (frames processed; the working resolution in pixels).
      trajectory: the trajectory errors, or None without ground truth (fewer than 3 valid GT poses).
      constant_pose_ate_rmse_c2w_cm: the ATE of a camera that never moves (the baseline), or None.
      render: rendering metrics; cbknn: CB-KNN's diagnostics, or None when it did not smooth renders.
      frames_per_s, seconds_per_frame: SLAM throughput (compilation included), or None.
      stage_timings_s: seconds per stage (``read_frames_s``, ``slam_s``, ``checkpoint_s``, ...).
      num_gaussians, capacity, keyframes: the final map's active Gaussians, its slots, the keyframes stored.
      nonfinite_*, frames_with_truncated_render, max_truncation_residual: numerical health counters.
      skipped_frames, retried_frames, diverged_frames, keyframe_frames: frame numbers.
      checkpoints: the checkpoints written, or None; warnings: every warning of the run.
      camera: intrinsics at the working resolution and ``depth_scale``; config: the SLAM config as a dict.
      world_from_map: [4][4] map (first camera) coordinates -> the trajectory file's frame.
      per_frame: one list per :data:`gsjax.app.run_outputs.PER_FRAME` name, a value per frame (None: not finite).
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
        """The JSON object ``metrics.json`` holds (field names as keys, in field order)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, value: dict[str, Any]) -> RunMetrics:
        """The record of a ``metrics.json`` object. Raises ValueError naming a key whose value has the wrong shape."""
        return _record(cls, value)


def read_run_metrics(path: str | Path) -> RunMetrics:
    """Read a ``metrics.json``; raises ValueError naming the file when it cannot be read or is not one."""
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
