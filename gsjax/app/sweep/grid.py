"""``gsjax sweep``: a grid of configs over one sequence, run as one vmapped program per static signature.

The grid is the product of ``--grid FIELD=V1,V2`` axes times the run seeds. Configs that differ only in traced
fields (learning rates, loss weights, CB-KNN alpha / K0 / beta, noise levels, ...) share one compiled program; a
static field in the grid (an iteration count, a mode) gives one program per value. ``--batch B`` configs run at a
time over the same frames (:func:`gsjax.app.session.loop.chunk_loop`, bounding memory); within a batch,
``--vmap-width V`` configs are stacked and run as ``jax.vmap`` of the whole tracking + mapping scan, the stacked
axis sharded over every device of a 1-D mesh. With V = 1 (the CPU default: XLA:CPU runs the vmapped scan slower
per config than the plain one) each config is one call of the plain program, configs spread round-robin over the
devices and dispatched together, and every row is bit for bit the separate ``gsjax run``. On CPU the CLI asks for
one device per two cores (:func:`gsjax.app.sweep.devices.request_cpu_devices`), so that many configs run at once.

Multi-host: start every process with the same command and ``GSJAX_DISTRIBUTED=1`` (see
:func:`gsjax.app.sweep.devices.maybe_initialize_distributed`); the mesh then spans every process's devices. With V = 1
each process runs the configs of its own devices and the finished ones are gathered
(:func:`gsjax.app.sweep.devices.share_results`); a stacked group is
sharded over the processes and gathered after each chunk. Process 0 writes every output; the others write nothing.
Tested with two processes on one machine.

Outputs in ``DIR``: ``sweep.csv`` and ``sweep.md`` (a row per config), ``sweep.png`` (ATE heat map), ``sweep.json``
(the grid, programs and timings) and ``runs/NNN/`` per config (``trajectory.txt``, ``metrics.json``, ``config.json``
and the other outputs of ``gsjax run``).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import itertools
import math
import time
from pathlib import Path

import jax
import numpy as np

from gsjax.app.run_folder.layout import check_run_dir, clear_previous_run, locked_run_dir
from gsjax.app.runtime.cache import exported_call
from gsjax.app.runtime.progress import Progress
from gsjax.app.session.loop import Group, Runtime, chunk_loop, sequence_frames
from gsjax.app.sweep.devices import batch_mesh, place_batch, share_results, to_host
from gsjax.app.sweep.resume import finished_runs, prepare_rerun
from gsjax.config.text import apply_overrides
from gsjax.data.sequence import Sequence
from gsjax.eval.run_metrics import RunMetrics
from gsjax.io.atomic import atomic_write_bytes, atomic_write_json, remove_stale_temporaries
from gsjax.io.run_folder import SWEEP_FILES, sweep_run
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import concat_outputs, stack_trees, start_capacity, static_key, unstack_tree
from gsjax.slam.loops import LoopCaps, common_caps
from gsjax.slam.state import initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs

CSV_METRICS = ("seed", "ate_rmse_cm", "ate_splatam_cm", "psnr_db", "depth_l1_cm", "seconds", "run")


@dataclasses.dataclass(frozen=True)
class GridAxis:
    """One ``--grid FIELD=V1,V2`` axis: a config field's dotted name and its values as given."""

    field: str
    values: tuple[str, ...]


def parse_grid(text: str) -> GridAxis:
    """``FIELD=V1,V2[,...]`` -> GridAxis; ValueError naming ``--grid`` on a malformed axis."""
    field, sep, values = text.partition("=")
    items = tuple(v.strip() for v in values.split(",") if v.strip())
    if not sep or not field.strip() or not items:
        raise ValueError(f"--grid {text!r}: expected FIELD=V1,V2,... (e.g. cbknn.params.alpha=0.1,0.2)")
    if len(set(items)) != len(items):
        raise ValueError(f"--grid {text!r}: a value is repeated")
    return GridAxis(field.strip(), items)


@dataclasses.dataclass(frozen=True)
class SweepPoint:
    """One config of the grid: ``index`` (its ``runs/NNN``), the swept ``values`` by field, the ``seed``."""

    index: int
    values: dict
    seed: int
    config: SlamConfig


def expand_grid(base: SlamConfig, axes: list[GridAxis], seeds: list[int]) -> list[SweepPoint]:
    """The product of the axes (first axis slowest) times the seeds, each value applied to ``base`` as an override
    (so read and validated as ``gsjax run --FIELD V`` would be). Every config is given the same loop caps (those
    that hold every config's iteration counts: :meth:`gsjax.slam.config.SlamConfig.with_caps`), so that iteration
    counts, like every other traced field, share one program; ``cbknn.mode`` ``paper`` (the renders' correction
    compiled in) is one program and the other modes another."""
    fields = [axis.field for axis in axes]
    if len(set(fields)) != len(fields):
        raise ValueError("--grid: a field appears in more than one axis")
    points = []
    for combo in itertools.product(*(axis.values for axis in axes)):
        values = dict(zip(fields, combo))
        try:
            config = apply_overrides(base, values)
        except ValueError as err:
            raise ValueError(f"--grid: {err}") from None
        for seed in seeds:  # seeds innermost: a config's seeds are adjacent rows
            points.append(SweepPoint(len(points), values, seed, config))
    caps = common_caps([p.config for p in points])
    return [dataclasses.replace(p, config=_pinned(p.config, caps)) for p in points]


def _pinned(config: SlamConfig, caps: LoopCaps) -> SlamConfig:
    """``config`` on the sweep's common loop caps, with its own :attr:`LoopCaps.smoothing`: CB-KNN's correction
    compiled in costs a run that never smooths 8-11 % of its SLAM time on XLA:CPU, so ``paper`` and the other modes
    stay two programs (each row then the very program of its separate run)."""
    return config.with_caps(dataclasses.replace(caps, smoothing=config.caps.smoothing))


def group_by_program(points: list[SweepPoint]) -> list[list[SweepPoint]]:
    """Points grouped by their compiled program (same static fields), in grid order."""
    groups: dict = {}
    for point in points:
        groups.setdefault(static_key(point.config), []).append(point)
    return list(groups.values())


def static_fields(base: SlamConfig, axes: list[GridAxis]) -> list[str]:
    """The swept fields whose values change the compiled program (static fields; iteration counts share the sweep's
    common caps and do not)."""
    statics = []
    for axis in axes:
        configs = [apply_overrides(base, {axis.field: v}) for v in axis.values]
        caps = common_caps(configs)
        if len({static_key(_pinned(c, caps)) for c in configs}) > 1:
            statics.append(axis.field)
    return statics


# ------------------------------------------------------------------------------------------ batches and placement


def batch_size(requested: int | None, configs: int) -> int:
    """Configs per batch (alive at once, bounding memory): ``requested`` (default: all), at most ``configs``."""
    return min(requested or configs, configs)


def vmap_width(requested: int | None, devices: int) -> int:
    """Configs vmapped into one program call: ``requested``, else 1 on CPU and 64 elsewhere; a multiple of the
    device count when above 1 (each device takes an equal slice).

    On XLA:CPU the vmapped SLAM scan is slower per config than the plain one (measured: 1.6x for a batch of 1,
    3.2x per config for a batch of 4, at 40x30), so CPU sweeps run the plain compiled program once per config,
    configs on different devices at the same time."""
    width = requested or (1 if jax.default_backend() == "cpu" else 64)
    return width if width == 1 else devices * math.ceil(width / devices)


def _groups(states: list, configs: list, width: int, mesh):
    """The batch as program-call groups: single configs placed round-robin on the devices (``width`` 1), or
    ``width`` configs stacked and sharded over the mesh (the last group padded with repeats of its last config).
    -> (groups, the batch indices each group holds, the placement function for grown states)."""
    devices = list(mesh.devices.flat)
    if width == 1:  # config i on device i mod D; a process runs the configs of its own devices
        local = [i for i in range(len(states)) if devices[i % len(devices)].process_index == jax.process_index()]
        groups = [Group(jax.device_put(states[i], devices[i % len(devices)]),
                        jax.device_put(configs[i], devices[i % len(devices)])) for i in local]
        return (groups, [[i] for i in local],
                lambda g, s: jax.device_put(s, devices[local[g] % len(devices)]))
    groups, members = [], []
    for begin in range(0, len(states), width):
        index = list(range(begin, min(begin + width, len(states))))
        padded = index + [index[-1]] * (width - len(index))  # repeats keep the program's batch shape
        groups.append(Group(place_batch(stack_trees([states[i] for i in padded]), mesh),
                            place_batch(stack_trees([configs[i] for i in padded]), mesh), stacked=True))
        members.append(index)
    return groups, members, lambda g, s: place_batch(s, mesh)


def _per_config(groups, members, parts, final_states, count):
    """(final state, outputs [T, ...]) per batch entry, from the groups' per-chunk outputs; None for the configs
    another process ran."""
    out = [None] * count
    for g, (group, index) in enumerate(zip(groups, members)):
        outputs = concat_outputs([chunk[g] for chunk in parts], batched=group.stacked)
        state = to_host(final_states[g]) if group.stacked else final_states[g]
        for j, i in enumerate(index):
            if group.stacked:
                out[i] = (unstack_tree(state, j), unstack_tree(outputs, j))
            else:
                out[i] = (final_states[g], outputs)
    return out


# ------------------------------------------------------------------------------------------ the sweep


@dataclasses.dataclass(frozen=True)
class SweepOptions:
    """Shell options of a sweep: ``out`` directory, frames per ``chunk``, ``batch`` configs per program call
    (None: all), ``eval_every`` and ``samples`` as in ``gsjax run``, ``progress`` bar, ``overwrite``, ``resume``
    (run only the configs a previous sweep into ``out`` did not finish: :mod:`gsjax.app.sweep.resume`)."""

    out: Path
    chunk: int = 8
    batch: int | None = None
    vmap_width: int | None = None
    eval_every: int = 5
    samples: int = 1
    progress: bool = True
    overwrite: bool = False
    resume: bool = False

    def __post_init__(self):
        for name in ("chunk", "eval_every", "samples"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        for name in ("batch", "vmap_width"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")


def run_sweep(sequence: Sequence, base: SlamConfig, axes: list[GridAxis], seeds: list[int], options: SweepOptions,
              *, describe: dict | None = None, input_warnings: tuple[str, ...] = (), say=print) -> list[dict]:
    """Run the grid of ``axes`` x ``seeds`` over ``base`` on ``sequence``; write ``runs/NNN`` per config and the
    sweep tables; return the rows (one dict per config, the columns of ``sweep.csv``). The writing process holds
    ``options.out``'s lock (:func:`gsjax.app.run_folder.layout.locked_run_dir`) while it runs."""
    out = Path(options.out)
    writer = jax.process_index() == 0  # the other processes of a multi-host sweep write nothing
    if writer:
        check_run_dir(out, resume=options.resume, overwrite=options.overwrite, outputs=SWEEP_FILES)
    sequence.read_host(0)  # an unreadable first frame fails before anything in ``out`` changes
    with locked_run_dir(out) if writer else contextlib.nullcontext():
        return _sweep(sequence, base, axes, seeds, options, writer, describe, input_warnings, say)


def _sweep(sequence: Sequence, base: SlamConfig, axes: list[GridAxis], seeds: list[int], options: SweepOptions,
           writer: bool, describe: dict | None, input_warnings: tuple[str, ...], say) -> list[dict]:
    from gsjax.app.run_folder.checkpoints import RunLedger
    from gsjax.app.run_folder.outputs import OutputOptions, run_record
    from gsjax.app.session.recorder import Recorder
    from gsjax.eval.renders import is_evaluation_frame

    points = expand_grid(base, axes, seeds)
    out = Path(options.out)
    if writer:
        if options.overwrite:
            clear_previous_run(out, SWEEP_FILES)
        out.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(out)
    k = sequence.intrinsics
    height, width_px, total = k.height, k.width, len(sequence)
    done = {}
    if options.resume:  # every process reads the same folder, so all agree on what is left
        done = finished_runs(out, {p.index: run_record(sequence, p.config, chunk=options.chunk, seed=p.seed,
                                                       describe=describe, frames=total, sweep=dict(values=p.values))
                                   for p in points})
        say(f"gsjax sweep --resume: {len(done)} of {len(points)} configs finished before; running the other "
            f"{len(points) - len(done)}")
        for point in points:
            if writer and point.index not in done:
                prepare_rerun(out, point.index)
    mesh = batch_mesh()
    devices = mesh.devices.size
    groups = group_by_program([p for p in points if p.index not in done])
    statics = static_fields(base, axes)
    if statics:
        say(f"gsjax sweep: {', '.join(statics)} {'changes' if len(statics) == 1 else 'change'} the compiled program "
            f"(a static field, or cbknn.mode paper: CB-KNN's correction compiled into the renders), {len(groups)} "
            "programs")
    batches = []
    for group in groups:
        size = batch_size(options.batch, len(group))
        batches += [group[i:i + size] for i in range(0, len(group), size)]
    width = vmap_width(options.vmap_width, devices)
    say(f"gsjax sweep: {len(points)} configs in {len(groups)} program(s), {len(batches)} batch(es) of up to "
        f"{max((len(b) for b in batches), default=0)} on {devices} device(s), {width} config(s) vmapped per program "
        f"call, {total} frames each")
    progress = Progress(total * len(batches), 0, options.progress and writer)
    rows = [_row(p, done[p.index], done[p.index].stage_timings_s.get("slam_s"),
                 sweep_run(out, p.index).relative_to(out)) for p in points if p.index in done]
    timings = dict(slam_s=0.0, regrow_s=0.0, read_frames_s=0.0, outputs_s=0.0, first_chunk_s=[])
    t_start = time.perf_counter()
    used_devices: set = set()
    try:
        for number, batch in enumerate(batches):
            kf_capacity = keyframe_capacity_for(total, batch[0].config.keyframe_every)
            states = [initial_state(start_capacity(height, width_px), height, width_px, kf_capacity, total, p.seed)
                      for p in batch]
            groups_, members, place = _groups(states, [p.config for p in batch], width, mesh)

            def on_grow(group, dropped, first, last, capacity, number=number):
                progress.write(f"capacity: batch {number + 1}, configs {members[group]}: {dropped} new Gaussians "
                               f"found no free slot at frames {first}-{last}; growing to {capacity} slots and "
                               "re-running the chunk")

            parts, slam_s, regrow_s, first, final_states, kept = [], 0.0, 0.0, None, [], {}
            for chunk in chunk_loop(groups_, sequence_frames(sequence), k, chunk=options.chunk, on_grow=on_grow,
                                    runtime=Runtime(exported_call(), place, to_host)):
                parts.append(chunk.outputs)
                kept.update((chunk.start + i, frame) for i, frame in enumerate(chunk.frames)
                            if is_evaluation_frame(chunk.start + i, options.eval_every))
                final_states = chunk.states
                slam_s += chunk.seconds
                regrow_s += chunk.regrow_seconds
                timings["read_frames_s"] += chunk.read_seconds
                first = chunk.seconds if first is None else first
                progress.update(chunk.count, batch=f"{number + 1}/{len(batches)}")
            timings["slam_s"] += slam_s
            timings["regrow_s"] += regrow_s
            timings["first_chunk_s"].append(first)
            for state in final_states:  # this process's groups
                used_devices |= {d.id for d in state.gaussians.means.devices()}
            per_config = share_results(_per_config(groups_, members, parts, final_states, len(batch)),
                                       name=f"batch{number}")
            t0 = time.perf_counter()
            for i, point in enumerate(batch):
                state, outputs = per_config[i]
                run_dir = sweep_run(out, point.index)
                run_outputs = StepOutputs(*(np.asarray(v) for v in outputs))
                record = run_record(sequence, point.config, chunk=options.chunk, seed=point.seed, describe=describe,
                                    frames=total, sweep=dict(values=point.values, batch=number, batch_size=len(batch)))
                seconds = (slam_s + regrow_s) / len(batch)
                run_timings = dict(slam_s=seconds, batch_slam_s=slam_s, batch_regrow_s=regrow_s,
                                   batch_size=len(batch))
                if writer:
                    run_dir.mkdir(parents=True, exist_ok=True)
                    recorder = Recorder(record, OutputOptions(run_dir, options.eval_every, options.samples),
                                        RunLedger(capacity=int(state.gaussians.capacity), record={},
                                                  frames_done=total, timings=run_timings),
                                        outputs=run_outputs, kept=kept)
                    metrics = recorder.finish(sequence, point.config, jax.device_get(state),
                                              input_warnings=input_warnings)
                    rows.append(_row(point, metrics, seconds, run_dir.relative_to(out)))
            timings["outputs_s"] += time.perf_counter() - t0
    finally:
        progress.close()
    rows.sort(key=lambda r: r["run"])
    if writer:
        fields = [axis.field for axis in axes]
        _write_tables(out, rows, fields)
        from gsjax.io.plots import plot_sweep_heatmap

        plot_sweep_heatmap(out / "sweep.png", rows, fields,
                           title=f"{sequence.name}: ATE RMSE (cm), mean over {len(seeds)} seed(s)")
        atomic_write_json(out / "sweep.json", dict(
            describe or {}, grid={a.field: list(a.values) for a in axes}, seeds=sorted({p.seed for p in points}),
            configs=len(points), programs=len(group_by_program(points)), static_fields=statics, batches=len(batches),
            devices=devices, state_devices=len(used_devices), vmap_width=width, frames=total, width=width_px,
            height=height, wall_s=time.perf_counter() - t_start,
            timings=timings, warnings=list(input_warnings)))
    return rows


def _row(point: SweepPoint, metrics: RunMetrics, seconds: float, run: Path) -> dict:
    traj = metrics.trajectory
    render = metrics.render.mean or {}
    row = dict(point.values)
    row.update(seed=point.seed, ate_rmse_cm=metrics.ate_cm,
               ate_splatam_cm=traj.ate_splatam_mean_w2c_cm if traj else None, psnr_db=metrics.psnr_db,
               depth_l1_cm=render.get("depth_l1_cm"), seconds=seconds, run=run.as_posix())
    return row


def _format(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _write_tables(out: Path, rows: list[dict], fields: list[str]) -> None:
    columns = [*fields, *CSV_METRICS]
    buffer = io.StringIO()
    table = csv.writer(buffer, lineterminator="\n")
    table.writerow(columns)
    for row in rows:
        table.writerow([_format(row[c]) for c in columns])
    atomic_write_bytes(out / "sweep.csv", buffer.getvalue().encode())
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        lines.append("| " + " | ".join(_format(row[c]) for c in columns) + " |")
    atomic_write_bytes(out / "sweep.md", ("\n".join(lines) + "\n").encode())


def read_sweep_csv(path: Path) -> list[dict]:
    """The rows of a ``sweep.csv`` (values as strings)."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
