"""A run's folder in one place: the names of its files, where a sweep puts its runs, writing the records it holds,
and reading a finished run back (for the report, the viewer and a sweep's resume).

A run's folder holds ``config.json`` (what the run was given, written first; :class:`gsjax.eval.run_input.RunInput`),
``checkpoints/``, ``trajectory.txt`` (camera-to-world, in the dataset's world frame when frame 0 has ground truth),
``groundtruth.txt`` (the dataset's poses, when it has any), ``trajectory.png``, ``renders/`` (``frame_T.png``
render-vs-input panels, ``cbknn_T.png`` CB-KNN's maps), ``map.ply`` (in the SLAM world frame, the first camera's;
``metrics.json``'s ``world_from_map`` takes it to the trajectory's frame), ``report.html`` and, written last,
``metrics.json`` (:class:`gsjax.eval.run_metrics.RunMetrics`): its presence marks a finished run. A sweep's folder
holds its tables and one run folder per config, ``runs/NNN``.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np

from gsjax.camera import invert_transform
from gsjax.eval.association import associate_timestamps
from gsjax.eval.run_input import RunInput, read_run_input
from gsjax.eval.run_metrics import RunMetrics, read_run_metrics
from gsjax.eval.trajectory import Drift, drift, ground_truth_on_estimate
from gsjax.io.atomic import atomic_write_json
from gsjax.io.trajectory import read_tum_trajectory

CONFIG = "config.json"
CHECKPOINTS = "checkpoints"
TRAJECTORY = "trajectory.txt"
GROUNDTRUTH = "groundtruth.txt"
METRICS = "metrics.json"
TRAJECTORY_PLOT = "trajectory.png"
RENDERS = "renders"
MAP = "map.ply"
REPORT = "report.html"
# Every file and folder a run writes directly under its folder, in the order they are written.
RUN_FILES = (CONFIG, CHECKPOINTS, TRAJECTORY, GROUNDTRUTH, TRAJECTORY_PLOT, RENDERS, MAP, REPORT, METRICS)
# ... of a sweep and of a landscape.
SWEEP_FILES = ("sweep.csv", "sweep.md", "sweep.png", "sweep.json", "runs", REPORT)
LANDSCAPE_FILES = ("landscape.json", "landscape.png", "landscape2d.png")
TUNE_FILES = ("tuned.json", "tune.csv", "tune.png")


def sweep_run(out: str | Path, index: int) -> Path:
    """The folder of config ``index`` of the sweep in ``out``: ``runs/NNN``."""
    return Path(out) / "runs" / f"{index:03d}"


def render_panel(folder: str | Path, frame: int) -> Path:
    """Frame ``frame``'s render-vs-input panel."""
    return Path(folder) / RENDERS / f"frame_{frame:06d}.png"


def cbknn_panel(folder: str | Path, frame: int) -> Path:
    """Frame ``frame``'s CB-KNN K and rho maps."""
    return Path(folder) / RENDERS / f"cbknn_{frame:06d}.png"


def write_config(folder: str | Path, record: RunInput) -> None:
    """``config.json`` (atomically)."""
    atomic_write_json(Path(folder) / CONFIG, record.to_json())


def write_metrics(folder: str | Path, metrics: RunMetrics) -> None:
    """``metrics.json`` (atomically; written last, it marks the run finished)."""
    atomic_write_json(Path(folder) / METRICS, metrics.to_json())


def is_finished(folder: str | Path) -> bool:
    """Whether ``folder`` holds a finished run (its ``metrics.json``)."""
    return (Path(folder) / METRICS).exists()


def read_config(folder: str | Path) -> RunInput:
    """``config.json`` of the run in ``folder``; ValueError naming the file when it cannot be read."""
    return read_run_input(Path(folder) / CONFIG)


def read_metrics(folder: str | Path) -> RunMetrics:
    """``metrics.json`` of the run in ``folder``; ValueError naming the file when it cannot be read."""
    return read_run_metrics(Path(folder) / METRICS)


class RunRecordError(ValueError):
    """A directory is not a finished gsjax run, or one of its files cannot be read; the message names it."""


@dataclasses.dataclass(frozen=True)
class RunRecord:
    """One finished run.

    Attributes:
      path: the run directory; name: how the report names it (the directory's name, unless that is ambiguous).
      metrics: ``metrics.json``'s record; record: ``config.json``'s (dataset, preset, CB-KNN mode, camera, config,
        ...), or None when the run has none.
      timestamps: [T] s; est_c2w: [T, 4, 4] camera-to-world (m), as in ``trajectory.txt``.
      gt_timestamps, gt_c2w: ``groundtruth.txt`` ([M] s, [M, 4, 4]), or None.
      panels: ``renders/frame_T.png`` as (T, path), by frame; cbknn_panels: ``renders/cbknn_T.png`` likewise.
    """

    path: Path
    name: str
    metrics: RunMetrics
    record: RunInput | None
    timestamps: np.ndarray
    est_c2w: np.ndarray
    gt_timestamps: np.ndarray | None
    gt_c2w: np.ndarray | None
    panels: tuple[tuple[int, Path], ...]
    cbknn_panels: tuple[tuple[int, Path], ...]

    @property
    def world_from_map(self) -> np.ndarray:
        """[4, 4]: map (SLAM world) coordinates -> the trajectory file's frame (identity for runs that predate it)."""
        world_from_map = self.metrics.world_from_map
        return np.eye(4) if world_from_map is None else np.asarray(world_from_map, np.float64)

    def map_c2w(self) -> np.ndarray:
        """[T, 4, 4] the estimated camera-to-world poses in the map's frame (what renders the map at each frame)."""
        return invert_transform(self.world_from_map) @ self.est_c2w

    def ground_truth_in_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(estimate rows [n] int, the GT camera-to-world [n, 4, 4] associated with them by timestamp, in the map's
        frame, starting at the estimate's pose: :func:`gsjax.eval.trajectory.ground_truth_on_estimate`), or None
        without ground truth."""
        if self.gt_c2w is None:
            return None
        rows, gt_rows = associate_timestamps(self.timestamps, self.gt_timestamps)
        on_estimate = ground_truth_on_estimate(self.map_c2w()[rows], self.gt_c2w[gt_rows]) if len(rows) else None
        return None if on_estimate is None else (rows[on_estimate[0]], on_estimate[1])

    def drift(self) -> Drift | None:
        """The camera error without alignment per frame (:func:`gsjax.eval.trajectory.drift`), its ``frames`` the
        estimate rows of :meth:`ground_truth_in_map`; None without ground truth."""
        aligned = self.ground_truth_in_map()
        if aligned is None:
            return None
        rows, gt_c2w = aligned
        found = drift(self.map_c2w()[rows], gt_c2w)
        return None if found is None else found._replace(frames=rows[found.frames])


def _read_json(path: Path, required: bool) -> dict | None:
    if not path.is_file():
        if required:
            raise RunRecordError(f"{path.parent} has no {path.name}: not a finished gsjax run (a run writes it last; "
                                 "continue an interrupted one with gsjax run --resume)")
        return None
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RunRecordError(f"{path}: cannot be read as JSON ({error})") from None
    if not isinstance(value, dict):
        raise RunRecordError(f"{path}: expected a JSON object, got {type(value).__name__}")
    return value


def _read_trajectory(path: Path, required: bool):
    if not path.is_file():
        if required:
            raise RunRecordError(f"{path.parent} has no {path.name}: not a finished gsjax run")
        return None, None
    try:
        return read_tum_trajectory(path)
    except ValueError as error:
        raise RunRecordError(str(error)) from None


def _frames_of(directory: Path, prefix: str) -> tuple[tuple[int, Path], ...]:
    pattern = re.compile(rf"{prefix}_(\d+)\.png")
    found = [(int(m.group(1)), p) for p in directory.glob(f"{prefix}_*.png") if (m := pattern.fullmatch(p.name))]
    return tuple(sorted(found))


def read_run(path: str | Path, metrics: RunMetrics | None = None) -> RunRecord:
    """Read the run in ``path``; ``metrics`` stands in for ``metrics.json`` while a run writes its outputs.

    Raises :class:`RunRecordError` naming the directory or file when it is not a finished run or a file is damaged.
    """
    path = Path(path)
    if not path.is_dir():
        raise RunRecordError(f"{path}: no such run directory")
    if metrics is None:
        value = _read_json(path / METRICS, required=True)
        try:
            metrics = RunMetrics.from_json(value)
        except ValueError as error:
            raise RunRecordError(f"{path / METRICS}: {error}") from None
    value = _read_json(path / CONFIG, required=False)
    try:
        record = None if value is None else RunInput.from_json(value)
    except ValueError as error:
        raise RunRecordError(f"{path / CONFIG}: {error}") from None
    timestamps, est_c2w = _read_trajectory(path / TRAJECTORY, required=True)
    gt_timestamps, gt_c2w = _read_trajectory(path / GROUNDTRUTH, required=False)
    renders = path / RENDERS
    return RunRecord(path=path, name=path.name, metrics=metrics, record=record, timestamps=timestamps, est_c2w=est_c2w,
                     gt_timestamps=gt_timestamps, gt_c2w=gt_c2w, panels=_frames_of(renders, "frame"),
                     cbknn_panels=_frames_of(renders, "cbknn"))


def expand_runs(paths: list[str | Path]) -> list[Path]:
    """The run directories ``paths`` name: a sweep's directory (with ``sweep.json``) stands for its ``runs/*``."""
    runs = []
    for path in map(Path, paths):
        if (path / "sweep.json").is_file() and (path / "runs").is_dir():  # SWEEP_FILES
            runs += sorted(p for p in (path / "runs").iterdir() if p.is_dir())
        else:
            runs.append(path)
    return runs
