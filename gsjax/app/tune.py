"""``gsjax tune``: gradient-based search over traced config fields by hypergradients (:mod:`gsjax.slam.hypergrad`).

Each step records SLAM over the recording's frames at the current values (one frame at a time, the exported
program of ``gsjax run``), takes the objective's hypergradient (unrolled through tracking, each frame's state held
fixed: ``truncation="frame"``) and moves the fields by Adam (optax) in the search space: the logarithm of a
learning rate (a field named ``lr_...``), the value over its start's magnitude for the others; values are kept within
their declared bounds. A step after which the runs' objective is higher than the lowest seen is taken back: the next
one starts from the best values with half the step size. The values with the lowest objective seen are the result.

Writes into ``--out``: ``tuned.json`` (``{"fields": {name: value}, ...}``: ``gsjax run --tuned FILE`` applies them,
as do the dotted overrides ``--name value``), ``tune.csv`` (a row per step: ``step``, ``objective``, each field, each
field's gradient ``d_<field>``), ``tune.png`` (the objective and the fields over the steps).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import time
from pathlib import Path

import numpy as np

from gsjax.app.run_folder.layout import clear_previous_run, locked_run_dir
from gsjax.app.runtime.cache import exported_call
from gsjax.app.runtime.progress import Progress
from gsjax.config.fields import FieldSpec
from gsjax.config.paths import differentiable_entry, replace_path, replace_paths
from gsjax.config.text import config_to_dict
from gsjax.data.sequence import Sequence
from gsjax.io.atomic import atomic_write_json, atomic_write_text
from gsjax.io.run_folder import TUNE_FILES
from gsjax.slam.config import SlamConfig

TUNED = "tuned.json"
_BOUND_MARGIN = 1e-6  # an open bound is kept this far inside (relative)


@dataclasses.dataclass(frozen=True)
class TuneOptions:
    """What ``gsjax tune`` was asked for.

    Attributes:
      out: the output folder.
      fields: the dotted names of the fields to tune (traced floats).
      starts: values to start from, by field (the others start at the config's).
      objective: ``"residual"`` or ``"ate"``.
      steps: the Adam steps (``steps + 1`` SLAM runs and hypergradients).
      step_size: Adam's step in the search space (0.25: a quarter of a rate's e-fold, of another field's start).
      seed: the SLAM runs' PRNG seed.
      overwrite: replace a previous tuning in ``out``.
      progress: show a progress bar.
    """

    out: Path
    fields: tuple[str, ...]
    starts: dict[str, float]
    objective: str = "residual"
    steps: int = 10
    step_size: float = 0.25
    seed: int = 0
    overwrite: bool = False
    progress: bool = True


@dataclasses.dataclass(frozen=True)
class _Axis:
    """One field's search coordinate: x = log(value) for a rate, value / scale otherwise."""

    name: str
    spec: FieldSpec
    log: bool
    scale: float

    def to_x(self, value: float) -> float:
        return math.log(value) if self.log else value / self.scale

    def value(self, x: float) -> float:
        value = math.exp(x) if self.log else x * self.scale
        low, high = self.spec.low, self.spec.high
        if low is not None:
            value = max(value, low + (abs(low) + 1.0) * _BOUND_MARGIN if self.spec.low_open else low)
        if high is not None:
            value = min(value, high - (abs(high) + 1.0) * _BOUND_MARGIN if self.spec.high_open else high)
        return value

    def dvalue_dx(self, value: float) -> float:
        return value if self.log else self.scale


def _is_rate(name: str) -> bool:
    """Whether the field ``name`` is a learning rate (``lr_...``), tuned on a log scale."""
    return name.rsplit(".", 1)[-1].startswith("lr_")


def tuning_start(config: SlamConfig, fields: tuple[str, ...], starts: dict[str, float]) -> SlamConfig:
    """``config`` with ``starts`` set, every field checked: a traced float field, its start within its bounds.

    Raises:
      ValueError: naming the field, for an unknown, static or non-float field, a start given for a field not tuned,
        or a start its declaration refuses.
    """
    if not fields:
        raise ValueError("--params names no field to tune")
    for name in fields:
        differentiable_entry(config, name)
    for name, value in starts.items():
        if name not in fields:
            raise ValueError(f"--{name} gives a start for a field not in --params ({', '.join(fields)})")
        config = replace_path(config, name, float(value))
    for name in fields:
        value = float(differentiable_entry(config, name).value)
        if _is_rate(name) and not value > 0:
            raise ValueError(f"{name} starts at {value:g}: a learning rate is tuned on a log scale, start it above 0")
    return config


def run_tune(sequence: Sequence, config: SlamConfig, options: TuneOptions,
             describe: dict | None = None) -> dict:
    """Tune ``options.fields`` on ``sequence`` from ``config`` (the starts applied); write the outputs.

    Args:
      sequence: the frames to tune on (all of them are run at every step).
      config: the SLAM config (preset, mode and overrides) before the starts.
      options: the fields, starts, objective, steps and output folder.
      describe: what the command line recorded about the input (tuned.json keeps it).

    Returns:
      The tuned.json document.
    """
    import optax

    from gsjax.slam import hypergrad

    config = tuning_start(config, options.fields, options.starts)
    entries = [differentiable_entry(config, name) for name in options.fields]
    starts = [float(entry.value) for entry in entries]
    axes = [_Axis(name, entry.spec, _is_rate(name), 1.0 if _is_rate(name) else (abs(start) or 1.0))
            for name, entry, start in zip(options.fields, entries, starts)]
    x = np.array([axis.to_x(start) for axis, start in zip(axes, starts)])
    optimizer = optax.scale_by_adam()
    state = optimizer.init(x)
    best_x, best_grad, best_value, scale = x, None, math.inf, 1.0
    frames = [sequence.read_host(i) for i in range(len(sequence))]
    intrinsics = sequence.intrinsics
    call = exported_call()
    rows: list[dict] = []
    out = Path(options.out)
    started = time.perf_counter()
    with locked_run_dir(out):  # held while tuning: one process at a time writes the folder
        if options.overwrite:
            clear_previous_run(out, TUNE_FILES)
        bar = Progress(options.steps + 1, 0, options.progress)
        try:
            for step in range(options.steps + 1):
                values = {a.name: a.value(float(xi)) for a, xi in zip(axes, x)}
                current = replace_paths(config, values)
                window = hypergrad.record(frames, current, intrinsics, seed=options.seed, call=call)
                result = hypergrad.hypergradient(window, current, intrinsics, options.fields,
                                                 objective=options.objective)
                rows.append(dict(step=step, objective=result.value, **values,
                                 **{f"d_{name}": result.gradient[name] for name in options.fields},
                                 seconds=time.perf_counter() - started))
                _write_steps(out / "tune.csv", rows, options.fields)  # every step: a stopped tuning keeps them
                bar.update(1, objective=f"{result.value:.5g}")
                if step == options.steps:
                    break
                grad_x = np.array([result.gradient[a.name] * a.dvalue_dx(values[a.name]) for a in axes])
                if not np.all(np.isfinite(grad_x)):
                    bar.write(f"step {step}: the hypergradient is not finite "
                              f"({dict(zip(options.fields, grad_x))}); stopping")
                    break
                if result.value <= best_value:
                    best_x, best_grad, best_value = x, grad_x, result.value
                else:  # the step raised the runs' objective: back to the best values, half the step
                    x, grad_x, scale = best_x, best_grad, scale / 2
                updates, state = optimizer.update(grad_x, state)
                x = x - options.step_size * scale * np.asarray(updates)
                x = np.array([a.to_x(a.value(float(xi))) for a, xi in zip(axes, x)])  # back within the bounds
        finally:
            bar.close()
        best = min(rows, key=lambda row: row["objective"])
        document = dict(fields={name: best[name] for name in options.fields}, objective=options.objective,
                        value=best["objective"], step=best["step"],
                        start={name: rows[0][name] for name in options.fields}, start_value=rows[0]["objective"],
                        steps=len(rows) - 1, frames=len(frames), seconds=time.perf_counter() - started,
                        describe=describe or {}, config=config_to_dict(config))
        from gsjax.io.plots import plot_tuning

        plot_tuning(out / "tune.png", rows, list(options.fields), options.objective)
        atomic_write_json(out / TUNED, document)  # last: a finished tuning has it
    return document


def _write_steps(path: Path, rows: list[dict], fields: tuple[str, ...]) -> None:
    """``tune.csv``: a row per step so far (rewritten whole, atomically)."""
    text = io.StringIO()
    columns = ["step", "objective", *fields, *[f"d_{name}" for name in fields], "seconds"]
    writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: (f"{v:.9g}" if isinstance(v, float) else v) for k, v in row.items()} for row in rows)
    atomic_write_text(path, text.getvalue())


def read_tuned(path: str | Path) -> dict[str, float]:
    """The fields of a ``tuned.json`` (``gsjax run --tuned FILE``), checked to be a mapping of names to numbers.

    Args:
      path: the file.

    Returns:
      ``{field: value}``.

    Raises:
      ValueError: naming the file, when it cannot be read or has no ``fields`` mapping of numbers.
    """
    import json

    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise ValueError(f"--tuned {path}: cannot read it as JSON ({err})") from None
    fields = data.get("fields") if isinstance(data, dict) else None
    if not isinstance(fields, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                               for v in fields.values()):
        raise ValueError(f"--tuned {path}: expected {{\"fields\": {{\"name\": number, ...}}}} as gsjax tune writes it")
    return {str(k): float(v) for k, v in fields.items()}
