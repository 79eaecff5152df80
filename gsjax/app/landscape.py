"""``gsjax landscape``: frame T's tracking-loss landscape, CB-KNN ``off`` vs ``paper``, on the map of frames 0..T-1.

1. The map: SLAM over frames 0..T-1 (:func:`gsjax.slam.run`; ``--map-from gt`` maps them at their ground-truth
   poses instead, so the map has no tracking error).
2. The reference pose: frame T's ground-truth pose (in the SLAM world frame, the first camera), or, without ground
   truth, the pose the tracker gives frame T from the constant-velocity prediction.
3. Along each axis, at every grid offset: the tracking loss and its ``jax.grad`` (:mod:`gsjax.slam.landscape`), and
   whether the tracker started there returns to within 0.5 cm / 0.5 deg of the reference, for ``off`` (the
   canonical render) and ``paper`` (the smoothed render keyframe tracking uses, with its colour weight and CB-KNN's
   motion gamma from frames T-2, T-1), all on the same map.

Writes ``landscape.json`` and ``landscape.png`` into ``--out``.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.app.run_dir import LANDSCAPE_OUTPUTS, check_run_dir, clear_previous_run, locked_run_dir
from gsjax.config_text import config_to_dict
from gsjax.data.sequence import Sequence
from gsjax.io.atomic import atomic_write_json
from gsjax.slam import landscape as pure
from gsjax.slam.config import SlamConfig
from gsjax.slam.driver import run as slam_run
from gsjax.slam.presets import with_cbknn_mode
from gsjax.slam.system import tracking_problem
from gsjax.slam.tracking import track

MODES = ("off", "paper")


@dataclasses.dataclass(frozen=True)
class LandscapeOptions:
    """``frame`` T; ``axes`` names (:data:`gsjax.slam.landscape.AXES`); grid half-widths ``extent_cm`` and
    ``extent_deg``; ``steps`` grid points per axis; ``map_from`` ``"slam"`` or ``"gt"``; ``seed``; ``out``."""

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

    def __post_init__(self):
        unknown = [a for a in self.axes if a not in pure.AXES]
        if not self.axes or unknown or len(set(self.axes)) != len(self.axes):
            raise ValueError(f"--axes must name distinct axes among {', '.join(pure.AXES)}, got {','.join(self.axes)}")
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
    """Build the map, evaluate both modes' landscapes, write ``landscape.json`` / ``landscape.png``; return the
    JSON document."""
    out = Path(options.out)
    check_run_dir(out, overwrite=options.overwrite, outputs=LANDSCAPE_OUTPUTS)
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
        relative_gt = np.linalg.inv(np.linalg.inv(gt_c2w[0]) @ gt_c2w[: t + 1])  # w2c, world = the first camera
    t0 = time.perf_counter()
    poses = relative_gt[:t].astype(np.float32) if options.map_from == "gt" else None
    how = "at their ground-truth poses" if poses is not None else "SLAM"
    say(f"gsjax landscape: mapping frames 0..{t - 1} ({how})")
    built = slam_run(frames[:t], config, sequence.intrinsics, seed=options.seed, poses=poses, chunk=options.chunk)
    map_s = time.perf_counter() - t0
    # Frame T's problem exactly as SLAM's step poses it after frames 0..T-1 (prediction, motion, smooth flag).
    problem = tracking_problem(built.state, jnp.asarray(frames[t].color), jnp.asarray(frames[t].depth), config,
                               sequence.intrinsics)
    gamma = problem.gamma
    if relative_gt is not None:
        reference, w2c_ref = "gt", jnp.asarray(relative_gt[t], jnp.float32)
    else:  # what SLAM's step would give frame T: the tracker from the constant-velocity prediction
        reference, w2c_ref = "tracked", track(problem, config).w2c
    offsets = grid(options)
    directions = pure.directions(options.axes)
    document = dict(frame=t, reference=reference, reference_w2c=np.asarray(w2c_ref, np.float64).tolist(), axes={})
    for axis, row in zip(options.axes, offsets):
        document["axes"][axis] = dict(unit=pure.AXES[axis][1], offsets=[float(o) for o in row])
    timings = dict(map_s=map_s)
    for mode in MODES:
        t0 = time.perf_counter()
        mode_config = with_cbknn_mode(config, mode)
        # Around the reference pose; paper renders smoothed at every offset (as on a keyframe), off never.
        around = problem._replace(w2c_init=w2c_ref, smooth=jnp.bool_(mode == "paper"))
        result = jax.device_get(pure.landscape(around, mode_config, directions, jnp.asarray(offsets, jnp.float32)))
        timings[f"{mode}_s"] = time.perf_counter() - t0
        for i, axis in enumerate(options.axes):
            converged = (result.error_cm[i] <= pure.CONVERGED_CM) & (result.error_deg[i] <= pure.CONVERGED_DEG)
            document["axes"][axis][mode] = dict(
                loss=[float(v) for v in result.loss[i]], grad=[float(v) for v in result.grad[i]],
                basin=pure.basin_width(offsets[i], converged), converged=[bool(c) for c in converged],
                final_error_cm=[float(v) for v in result.error_cm[i]],
                final_error_deg=[float(v) for v in result.error_deg[i]])
        say(f"{mode}: " + ", ".join(f"{a} basin {document['axes'][a][mode]['basin']:g} {document['axes'][a]['unit']}"
                                    for a in options.axes))
    document.update(map_from=options.map_from, gamma=float(gamma), sequence=sequence.name, steps=options.steps,
                    converged_within=dict(cm=pure.CONVERGED_CM, deg=pure.CONVERGED_DEG), timings_s=timings,
                    describe=describe or {}, config=config_to_dict(config))
    from gsjax.io.plots import plot_landscape

    with locked_run_dir(out):  # one process at a time writes a directory; a previous landscape goes only now
        if options.overwrite:
            clear_previous_run(out, LANDSCAPE_OUTPUTS)
        atomic_write_json(out / "landscape.json", document)
        plot_landscape(out / "landscape.png", document, title=f"{sequence.name}, frame {t} (map: "
                                                                f"{options.map_from}, reference: {reference})")
    return document
