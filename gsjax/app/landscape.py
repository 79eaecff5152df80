"""``gsjax landscape``: frame T's tracking-loss landscape, CB-KNN ``off`` vs ``paper`` (or the ``modes`` asked for,
:data:`MODES`), on the map of frames 0..T-1.

1. The map: SLAM over frames 0..T-1 (:func:`gsjax.slam.run`; ``--map-from gt`` maps them at their ground-truth
   poses instead, so the map has no tracking error).
2. The reference pose: frame T's ground-truth pose (in the SLAM world frame, the first camera), or, without ground
   truth, the pose SLAM's step gives frame T (the tracker from the constant-velocity prediction, guarded), one more
   chunk of the map's program.
3. Along each axis, at every grid offset: the tracking loss and its ``jax.grad`` (:mod:`gsjax.slam.landscape`), and
   whether the tracker started there returns to within 0.5 cm / 0.5 deg of the reference (``basin``) and of its
   own fixed point, where it ends when started at the reference (``basin_fixed``: without the map's bias), for
   ``off`` (the canonical render) and ``paper`` (the smoothed render keyframe tracking uses, with its colour weight
   and CB-KNN's motion gamma from frames T-2, T-1), all on the same map.
4. With ``grid2d`` (two axes): the same over the plane of both axes, ``steps`` x ``steps`` points, so steps^2
   tracker runs per mode (beside the A steps + 1 of the axes); its basin is the largest normalised radius
   sqrt((a / e_a)^2 + (b / e_b)^2) (e the grid's half-widths) inside which every point converged
   (:func:`gsjax.slam.landscape.basin_2d`), with the fraction of the grid that converged.

Writes ``landscape.json`` and ``landscape.png`` (with ``grid2d`` also ``landscape2d.png``) into ``--out``.
JSON: ``axes[axis][mode]`` per axis and mode (loss, grad, converged, final errors, basin, and against the fixed
point converged_fixed, final_fixed_error_cm / _deg, basin_fixed); ``fixed_point[mode]`` (its w2c, its distance
from the reference, its offset along every axis); ``grid2d`` (axes, units, offsets per axis, and per mode
[S][S] lists indexed [i][j] = (offsets[axes[0]][i], offsets[axes[1]][j]), basin and area, each also _fixed).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.app.run_folder.layout import check_run_dir, clear_previous_run, locked_run_dir
from gsjax.app.runtime.cache import exported_call
from gsjax.camera import invert_transform, se3_inverse, se3_log
from gsjax.config.text import config_to_dict
from gsjax.data.sequence import Sequence
from gsjax.io.atomic import atomic_write_json
from gsjax.io.run_folder import LANDSCAPE_FILES
from gsjax.slam import landscape as pure
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import pad_chunk
from gsjax.slam.driver import run as slam_run
from gsjax.slam.presets import with_cbknn_mode, with_coarse_to_fine, with_image_smoothing
from gsjax.slam.system import run_chunk, tracking_problem, unknown_poses

# mode -> (its tracking config from the run's, whether frame T renders smoothed (CB-KNN, as on a keyframe)). A mode
# is one line here.
MODES: dict[str, tuple[Callable[[SlamConfig], SlamConfig], bool]] = {
    "off": (lambda config: with_cbknn_mode(config, "off"), False),
    "paper": (lambda config: with_cbknn_mode(config, "paper"), True),
    "blur": (lambda config: with_image_smoothing(with_cbknn_mode(config, "off")), False),
    "pyramid": (lambda config: with_coarse_to_fine(with_cbknn_mode(config, "off")), False),
}


@dataclasses.dataclass(frozen=True)
class LandscapeOptions:
    """``frame`` T; ``axes`` names (:data:`gsjax.slam.landscape.AXES`); grid half-widths ``extent_cm`` and
    ``extent_deg``; ``steps`` grid points per axis; ``map_from`` ``"slam"`` or ``"gt"``; ``seed``; ``out``;
    ``modes`` (keys of :data:`MODES`); ``grid2d``: also the plane of the two ``axes`` (steps^2 tracker runs per
    mode); ``batch``: tracker runs vmapped at a time (memory; None: 1 on a CPU, where XLA runs a vmapped tracker
    slower per run than one at a time (2 axes x 21 steps on 7-Scenes: 55 s against 59 s for the whole landscape with
    64), else 64)."""

    out: Path
    frame: int
    axes: tuple[str, ...] = ("tx", "ry")
    extent_cm: float = 4.0
    extent_deg: float = 4.0
    steps: int = 21
    map_from: str = "slam"
    seed: int = 0
    chunk: int = 8
    overwrite: bool = False
    modes: tuple[str, ...] = ("off", "paper")
    grid2d: bool = False
    batch: int | None = None

    def __post_init__(self):
        unknown = [a for a in self.axes if a not in pure.AXES]
        if not self.axes or unknown or len(set(self.axes)) != len(self.axes):
            raise ValueError(f"--axes must name distinct axes among {', '.join(pure.AXES)}, got {','.join(self.axes)}")
        if self.grid2d and len(self.axes) != 2:
            raise ValueError(f"--grid2d needs --axes naming exactly two axes, got {','.join(self.axes)}")
        unknown = [m for m in self.modes if m not in MODES]
        if not self.modes or unknown or len(set(self.modes)) != len(self.modes):
            raise ValueError(f"--modes must name distinct modes among {', '.join(MODES)}, got {','.join(self.modes)}")
        if self.batch is not None and self.batch < 1:
            raise ValueError(f"--batch must be >= 1, got {self.batch}")
        if self.steps < 2:
            raise ValueError(f"--steps must be >= 2, got {self.steps}")
        if not (self.extent_cm > 0 and self.extent_deg > 0):
            raise ValueError("--extent-cm and --extent-deg must be > 0")
        if self.map_from not in ("slam", "gt"):
            raise ValueError(f"--map-from must be slam or gt, got {self.map_from!r}")
        if self.frame < 1:
            raise ValueError(f"--frame must be >= 1 (the map is built from frames 0..T-1), got {self.frame}")


def grid(options: LandscapeOptions) -> np.ndarray:
    """[A, S] offsets per axis, in the axis's unit, symmetric about 0 (0 is on the grid when ``steps`` is odd)."""
    return np.stack([np.linspace(-e, e, options.steps) for e in
                     (options.extent_cm if pure.AXES[a][1] == "cm" else options.extent_deg for a in options.axes)])


def run_landscape(sequence: Sequence, config: SlamConfig, options: LandscapeOptions, *, describe: dict | None = None,
                  say=print) -> dict:
    """Build the map, evaluate each mode's landscapes, write ``landscape.json`` / ``landscape.png`` (and
    ``landscape2d.png``); return the JSON document."""
    out = Path(options.out)
    check_run_dir(out, overwrite=options.overwrite, outputs=LANDSCAPE_FILES)
    t = options.frame
    if t >= len(sequence):
        raise ValueError(f"--frame {t} is past the sequence's last frame ({len(sequence) - 1})")
    _, gt_c2w, gt_valid = sequence.gt_trajectory()
    if options.map_from == "gt" and not gt_valid[: t + 1].all():
        missing = int(np.flatnonzero(~gt_valid[: t + 1])[0])
        raise ValueError(f"--map-from gt needs ground truth for frames 0..{t}; {sequence.describe_frame(missing)} has "
                         "none")
    frames = [sequence.read_host(i) for i in range(t + 1)]
    relative_gt = None
    if gt_valid[0] and gt_valid[t]:
        relative_gt = invert_transform(invert_transform(gt_c2w[0]) @ gt_c2w[: t + 1])  # w2c, world = the first camera
    t0 = time.perf_counter()
    poses = relative_gt[:t].astype(np.float32) if options.map_from == "gt" else None
    how = "at their ground-truth poses" if poses is not None else "SLAM"
    say(f"gsjax landscape: mapping frames 0..{t - 1} ({how})")
    built = slam_run(frames[:t], config, sequence.intrinsics, seed=options.seed, poses=poses, chunk=options.chunk,
                     call=exported_call())
    mapped = time.perf_counter()
    map_s = mapped - t0
    # Frame T's problem exactly as SLAM's step poses it after frames 0..T-1 (prediction, motion, smooth flag).
    problem = tracking_problem(built.state, jnp.asarray(frames[t].color), jnp.asarray(frames[t].depth), config,
                               sequence.intrinsics)
    gamma = problem.gamma
    if relative_gt is not None:
        reference, w2c_ref = "gt", jnp.asarray(relative_gt[t], jnp.float32)
    else:  # what SLAM's step gives frame T: one more chunk of the map's own program, frame T then padding
        # As a host array, like the ground truth: the landscape's program is then the same for both references
        # (a device result is committed, and jit compiles anew for committed arguments).
        reference, w2c_ref = "tracked", jnp.asarray(np.asarray(_stepped_pose(built.state, frames[t], config,
                                                                             sequence.intrinsics, options.chunk)))
    offsets = grid(options)
    directions = pure.directions(options.axes)
    document = dict(frame=t, reference=reference, reference_w2c=np.asarray(w2c_ref, np.float64).tolist(), axes={},
                    modes=list(options.modes), fixed_point={})
    for axis, row in zip(options.axes, offsets):
        document["axes"][axis] = dict(unit=pure.AXES[axis][1], offsets=[float(o) for o in row])
    if options.grid2d:
        document["grid2d"] = dict(axes=list(options.axes), units=[pure.AXES[a][1] for a in options.axes],
                                  offsets={a: [float(o) for o in row] for a, row in zip(options.axes, offsets)})
    timings = dict(map_s=map_s)
    pending = []
    for mode in options.modes:
        configure, smooth = MODES[mode]
        # Around the reference pose; a smoothed mode renders smoothed at every offset (as on a keyframe). Each mode on
        # its own caps: paper's program carries CB-KNN's correction, the others' do not (on common caps `off` ran
        # 28 % slower warm, and the one compilation saved no time cold: experiments/README.md, "Compile less").
        around = problem._replace(w2c_init=w2c_ref, smooth=jnp.bool_(smooth))
        # Dispatched, not fetched: the next mode's program is traced and compiled while this one runs.
        pending.append((mode, pure.landscape(around, configure(config), directions, jnp.asarray(offsets, jnp.float32),
                                             plane=options.grid2d, batch=_batch(options.batch))))
    clock = mapped  # each mode's time: from the mapping's end, or the previous mode's result, to its result
    for mode, pending_result in pending:
        result = jax.device_get(pending_result)
        now = time.perf_counter()
        timings[f"{mode}_s"], clock = now - clock, now
        document["fixed_point"][mode] = _fixed_point(result.fixed_w2c, w2c_ref)
        for i, axis in enumerate(options.axes):
            document["axes"][axis][mode] = _line_entry(result, i, offsets[i])
        fixed, entries = document["fixed_point"][mode], [document["axes"][a] for a in options.axes]
        say(f"{mode}: " + ", ".join(f"{a} basin {e[mode]['basin']:g} {e['unit']} (to its fixed point "
                                    f"{e[mode]['basin_fixed']:g})" for a, e in zip(options.axes, entries))
            + f"; fixed point {fixed['error_cm']:.3g} cm, {fixed['error_deg']:.3g} deg from the reference")
        if options.grid2d:
            entry = document["grid2d"][mode] = _plane_entry(result.plane, offsets)
            say(f"{mode}: {' x '.join(options.axes)} basin radius {entry['basin']:.2f} of the extent (to its fixed "
                f"point {entry['basin_fixed']:.2f}), converged from {100 * entry['area']:.0f} % of the grid "
                f"({100 * entry['area_fixed']:.0f} %)")
    document.update(map_from=options.map_from, gamma=float(gamma), sequence=sequence.name, steps=options.steps,
                    converged_within=dict(cm=pure.CONVERGED_CM, deg=pure.CONVERGED_DEG), timings_s=timings,
                    describe=describe or {}, config=config_to_dict(config))
    from gsjax.io.plots import plot_landscape, plot_landscape2d

    title = f"{sequence.name}, frame {t} (map: {options.map_from}, reference: {reference})"
    with locked_run_dir(out):  # one process at a time writes a directory; a previous landscape goes only now
        if options.overwrite:
            clear_previous_run(out, LANDSCAPE_FILES)
        atomic_write_json(out / "landscape.json", document)
        plot_landscape(out / "landscape.png", document, title=title)
        if options.grid2d:
            plot_landscape2d(out / "landscape2d.png", document, title=title)
    return document


def _stepped_pose(state, frame, config: SlamConfig, intrinsics, chunk: int) -> jax.Array:
    """[4, 4] the pose SLAM's step gives ``frame`` after ``state`` (tracked from the constant-velocity prediction,
    with the divergence guard): a chunk of the program that built the map, ``frame`` then padding."""
    frames, valid = pad_chunk([frame], chunk)
    call = exported_call() or (lambda fn, *args: fn(*args))
    _, outputs = call(run_chunk, state, frames, valid, config, intrinsics, unknown_poses(chunk))
    return outputs.w2c[0]


def _batch(requested: int | None) -> int:
    return requested if requested is not None else (1 if jax.default_backend() == "cpu" else 64)


def _line_entry(result: pure.Landscape, i: int, offsets: np.ndarray) -> dict:
    """Axis ``i``'s entry of one mode: loss, grad, where the tracker ends, basins (vs reference, vs fixed point)."""
    converged = pure.converged(result.error_cm[i], result.error_deg[i])
    converged_fixed = pure.converged(result.fixed_error_cm[i], result.fixed_error_deg[i])
    return dict(loss=_floats(result.loss[i]), grad=_floats(result.grad[i]),
                basin=pure.basin_width(offsets, converged), converged=converged.tolist(),
                final_error_cm=_floats(result.error_cm[i]), final_error_deg=_floats(result.error_deg[i]),
                basin_fixed=pure.basin_width(offsets, converged_fixed), converged_fixed=converged_fixed.tolist(),
                final_fixed_error_cm=_floats(result.fixed_error_cm[i]),
                final_fixed_error_deg=_floats(result.fixed_error_deg[i]))


def _plane_entry(plane: pure.Landscape2d, offsets: np.ndarray) -> dict:
    """The 2-D grid's entry of one mode: [S][S] loss, converged masks and final errors; basin radii and areas."""
    converged = pure.converged(plane.error_cm, plane.error_deg)
    converged_fixed = pure.converged(plane.fixed_error_cm, plane.fixed_error_deg)
    basin, area = pure.basin_2d(offsets[0], offsets[1], converged)
    basin_fixed, area_fixed = pure.basin_2d(offsets[0], offsets[1], converged_fixed)
    return dict(loss=_floats(plane.loss), converged=converged.tolist(), converged_fixed=converged_fixed.tolist(),
                final_error_cm=_floats(plane.error_cm), final_error_deg=_floats(plane.error_deg),
                final_fixed_error_cm=_floats(plane.fixed_error_cm),
                final_fixed_error_deg=_floats(plane.fixed_error_deg),
                basin=basin, area=area, basin_fixed=basin_fixed, area_fixed=area_fixed)


def _floats(values) -> list:
    """An array of any rank as nested lists of floats."""
    return np.asarray(values, np.float64).tolist()


def _fixed_point(w2c: np.ndarray, w2c_ref: jax.Array) -> dict:
    """The fixed point's w2c, its distance from the reference (cm, deg) and its offset along every axis (the
    residual left perturbation's tangent in the axes' units)."""
    error_cm, error_deg = pure.pose_error(jnp.asarray(w2c), w2c_ref)
    tangent = np.asarray(se3_log(jnp.asarray(w2c) @ se3_inverse(w2c_ref)), np.float64)
    return dict(w2c=_floats(w2c), error_cm=float(error_cm), error_deg=float(error_deg),
                offsets={name: float(tangent[component] / scale) for name, (component, _, scale) in pure.AXES.items()})
