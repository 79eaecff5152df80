"""Where one steady-state SLAM frame of the ``cpu`` preset spends its time, stage by stage, and the floor.

Builds the map of frames 0..T-1 with the preset (``gsjax.slam.run``), then times frame T's stages as separate
jitted programs on that state (median of ``--repeats`` after a warm-up):

* ``step``: the whole frame (track -> densify -> window and map -> keyframe), as the scan runs it;
* ``track``, ``densify``, ``map`` (keyframe overlap, the window's views and all mapping iterations) and ``other``
  (the rest, and ops XLA left without a source location): the step's own stages, measured inside that one compiled
  program (:func:`step_stages`: JAX's profiler times every XLA op the step runs, each op is attributed to the
  ``jax.named_scope`` of :func:`gsjax.slam.system.step` its metadata names, and the shares of the op time are scaled
  to the step's median time; the profiler's own overhead inflates the op times, not the shares). Nothing is
  re-wired by hand, so the stages are exactly those of the program a run executes;
* the render's own stages (forward only): project, + bin, + select (the walk and the first-K extraction), the
  whole render; each row is the cumulative program, the difference to the previous row that stage's cost.

The host side of a run (reading frames, checkpoints, evaluation renders, output files, the report) comes from the
stage timings of a real ``gsjax run`` of ``--run-frames`` frames on the same sequence.

The floor: the arithmetic of one render's selection is one alpha evaluation per (pixel, candidate) pair up to the
pixel's stop; ``floor_alpha_ms`` times exactly that many evaluations as one fused dense XLA op on this machine, and
the slot memory the compositing touches (K x P slots x the fields read and written) is reported beside it.

    python experiments/profile_frame.py --sequence synthetic_noisy [--frame 16] [--repeats 5] [--out FILE.json]
    python experiments/profile_frame.py --sequence 7scenes --path ../shared/data/7scenes_redkitchen

``--compare NAME:FIELD=V,FIELD=V ...`` instead times the step and the tracker of each named override set on the
same state, the sets interleaved within each repeat (this machine's speed drifts by 10-30 % within minutes, so only
ratios taken side by side mean something); ``NAME:`` alone is the preset:

    python experiments/profile_frame.py --compare preset: fewer:tracking.iters=20
"""

from __future__ import annotations

import argparse
import gzip
import json
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.eval.run_metrics import read_run_metrics

ROOT = Path(__file__).resolve().parents[1]


def open_sequence_for(name: str, path: Path | None, frames: int):
    """(sequence, config) of the cpu preset at its working resolution, as ``gsjax run --preset cpu`` opens it."""
    from gsjax.data import open_sequence
    from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
    from gsjax.slam.presets import preset, working_downscale

    if name.startswith("synthetic"):
        base = SyntheticConfig()
        factor = working_downscale("cpu", base.width)
        config = SyntheticConfig(width=base.width // factor, height=base.height // factor, num_frames=frames)
        if name == "synthetic_noisy":
            config = config.with_sensor_noise()
        sequence = synthetic_sequence(config)
    else:
        probe = open_sequence(name, path, max_frames=1)
        sequence = open_sequence(name, path, max_frames=frames,
                                 downscale=working_downscale("cpu", probe.intrinsics.width))
    return sequence, preset("cpu", sequence.intrinsics.width)


def median_ms(fn, *args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))  # compile + warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


STAGES = ("track", "densify", "map")  # the jax.named_scope's in gsjax.slam.system.step


def step_stages(compiled, args, repeats: int, step_ms: float) -> dict:
    """Milliseconds of the compiled step's stages (:data:`STAGES`, ``other``): the profiled op time of each scope
    over ``repeats`` calls on ``args``, as its share of ``step_ms``; and the raw profiled op time per call."""
    scope_of = {}  # HLO instruction name -> the scope path of the op it was made from
    for line in compiled.as_text().splitlines():
        match = re.match(r"\s*(?:ROOT )?%?([\w.\-]+) = .*?metadata=\{[^}]*op_name=\"([^\"]+)\"", line)
        if match:
            scope_of[match.group(1)] = match.group(2).split("/")
    jax.block_until_ready(compiled(*args))
    totals = dict.fromkeys((*STAGES, "other"), 0.0)
    with tempfile.TemporaryDirectory() as trace:
        jax.profiler.start_trace(trace)
        for _ in range(repeats):
            jax.block_until_ready(compiled(*args))
        jax.profiler.stop_trace()
        for path in Path(trace).rglob("*.trace.json.gz"):
            for event in json.loads(gzip.decompress(path.read_bytes()))["traceEvents"]:
                op = event.get("args", {}).get("hlo_op")
                if event.get("ph") == "X" and op is not None:
                    stage = next((part for part in scope_of.get(op, ()) if part in STAGES), "other")
                    totals[stage] += event["dur"] / 1e3 / repeats  # us -> ms per call
    profiled = sum(totals.values())
    return dict(stages_ms={stage: step_ms * ms / profiled for stage, ms in totals.items()},
                profiled_op_ms=profiled)


def device_stages(sequence, config, frame_index: int, repeats: int) -> dict:
    """Milliseconds per stage of frame ``frame_index`` on the map SLAM built from the frames before it."""
    from gsjax import slam
    from gsjax.frame import to_device, without_ground_truth
    from gsjax.raster import render
    from gsjax.raster.binning import TileGrid, bin_gaussians
    from gsjax.raster.project import project
    from gsjax.raster.select import select_contributors
    from gsjax.slam.system import step

    intrinsics = sequence.intrinsics
    frames = [sequence.read_host(i) for i in range(frame_index + 1)]
    built = slam.run(frames[:frame_index], config, intrinsics, seed=0)
    state = built.state
    frame = to_device(without_ground_truth(frames[frame_index]))
    settings = config.raster
    grid = TileGrid.for_image(intrinsics.height, intrinsics.width, settings.tile_size)
    rows = {}

    compiled = jax.jit(lambda s, f, c: step(s, f, c, intrinsics)).lower(state, frame, config).compile()
    rows["step"] = median_ms(compiled, state, frame, config, repeats=repeats)
    inside = step_stages(compiled, (state, frame, config), repeats, rows["step"])
    rows.update(inside["stages_ms"])
    after, _ = compiled(state, frame, config)  # the renders below see the map and pose the step made
    g_dense, w2c = after.gaussians, after.w2c_prev1

    def projected(g, w):
        return project(g, w, intrinsics, settings.near)

    def binned(g, w):
        p = projected(g, w)
        return p, bin_gaussians(p.uv, p.extent, p.depth, p.visible, grid, settings.tile_capacity,
                                settings.intersection_capacity(g.capacity, grid))

    def selected(g, w):
        p, tiles = binned(g, w)
        return select_contributors(p, tiles, grid, settings.max_contributors, settings.tiles_per_batch, False)

    rows["render_project"] = median_ms(jax.jit(projected), g_dense, w2c, repeats=repeats)
    rows["render_bin"] = median_ms(jax.jit(binned), g_dense, w2c, repeats=repeats)
    rows["render_select"] = median_ms(jax.jit(selected), g_dense, w2c, repeats=repeats)
    rows["render_all"] = median_ms(jax.jit(lambda g, w: render(g, w, intrinsics, settings)), g_dense, w2c,
                                   repeats=repeats)

    # The floor of the selection's arithmetic: one alpha per (pixel, candidate) up to each pixel's stop, fused.
    p, tiles = jax.jit(binned)(g_dense, w2c)
    sel = jax.jit(selected)(g_dense, w2c)
    lists = np.minimum(np.asarray(tiles.count), settings.tile_capacity)
    in_image = np.asarray(grid.in_image())
    kept = np.asarray(sel.num_kept)[in_image]
    pixels = int(in_image.sum())
    pairs_listed = int((lists[:, None] * np.ones(grid.pixels_per_tile)).reshape(-1)[in_image].sum())
    pairs = max(pairs_listed, 1)
    columns = max(1, pairs // pixels)
    a = jax.random.uniform(jax.random.PRNGKey(2), (pixels, columns), minval=0.1, maxval=0.5)

    @jax.jit
    def alphas(a):
        dx, dy = a * 3.0, a * 2.0
        power = -0.5 * (a * dx * dx + a * dy * dy) - a * dx * dy
        return jnp.sum(jnp.minimum(0.5 * jnp.exp(power), 0.99) >= 1.0 / 255.0)

    floor = median_ms(alphas, a, repeats=repeats)
    k = settings.max_contributors
    return dict(
        stages_ms=rows,
        gaussians=int(g_dense.num_active()),
        capacity=int(g_dense.capacity),
        pixels=pixels,
        tiles=grid.num_tiles,
        mean_list=float(lists.mean()),
        longest_list=int(lists.max()),
        contributors_mean=float(kept.mean()),
        contributors_p99=float(np.percentile(kept, 99)),
        contributors_max=int(kept.max()),
        k=k,
        slot_fill=float(np.minimum(kept, k).mean() / k),
        pixel_candidate_pairs=pairs_listed,
        floor_alpha_ms=floor,
        slot_bytes_forward=k * grid.num_tiles * grid.pixels_per_tile * 11 * 4,
        profiled_op_ms=inside["profiled_op_ms"],
        tracking_iters=config.tracking.iters + config.tracking.strided_iters,
        mapping_iters=config.mapping.iters + config.mapping.strided_iters,
    )


def compare(sequence, config, frame_index: int, repeats: int, variants: dict) -> dict:
    """Median ms of the whole step and of the guarded tracker per named override set, interleaved per repeat."""
    from gsjax import slam
    from gsjax.config.text import apply_overrides
    from gsjax.frame import to_device, without_ground_truth
    from gsjax.slam.system import predicted_pose, step
    from gsjax.slam.tracking import TrackingProblem, track_guarded

    intrinsics = sequence.intrinsics
    frames = [sequence.read_host(i) for i in range(frame_index + 1)]
    state = slam.run(frames[:frame_index], config, intrinsics, seed=0).state
    frame = to_device(without_ground_truth(frames[frame_index]))
    w2c0 = predicted_pose(state)
    stages = dict(
        step=jax.jit(lambda c: step(state, frame, c, intrinsics)),
        track=jax.jit(lambda c: track_guarded(TrackingProblem(state.gaussians, frame.color, frame.depth, w2c0,
                                                              intrinsics, False, 0.0), c, jnp.float32(0))),
    )
    configs = {name: apply_overrides(config, overrides) for name, overrides in variants.items()}
    for c in configs.values():  # compile and warm up
        for fn in stages.values():
            jax.block_until_ready(fn(c))
    times = {name: {stage: [] for stage in stages} for name in configs}
    for _ in range(repeats):
        for name, c in configs.items():
            for stage, fn in stages.items():
                t0 = time.perf_counter()
                jax.block_until_ready(fn(c))
                times[name][stage].append(time.perf_counter() - t0)
    return {name: {stage: 1e3 * statistics.median(t) for stage, t in by_stage.items()}
            for name, by_stage in times.items()}


def host_stages(args, work: Path) -> dict:
    """Stage timings (s) of a real ``gsjax run`` of ``--run-frames`` frames (warm compile cache after the first)."""
    from gsjax.app.cli import main

    dataset = ["--dataset", "synthetic"] + (["--synthetic-noise"] if args.sequence == "synthetic_noisy" else [])
    if not args.sequence.startswith("synthetic"):
        dataset = ["--dataset", args.sequence, "--path", str(args.path)]
    out = work / "run"
    argv = ["run", *dataset, "--preset", "cpu", "--max-frames", str(args.run_frames), "--out", str(out),
            "--no-progress", "--overwrite"]
    for item in args.set:
        name, value = item.split("=", 1)
        argv += [f"--{name}", value]
    for _ in range(2):  # the first fills the compilation cache
        if main(argv) != 0:
            raise SystemExit("gsjax run failed")
    timings = read_run_metrics(out / "metrics.json").stage_timings_s
    timings["frames"] = args.run_frames
    return timings


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequence", default="synthetic_noisy",
                        choices=("synthetic", "synthetic_noisy", "7scenes", "tum", "replica", "scannet"))
    parser.add_argument("--path", type=Path, default=None)
    parser.add_argument("--frame", type=int, default=16, help="the profiled frame (the map is built from those before)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--run-frames", type=int, default=24, help="frames of the real run timed for the host side")
    parser.add_argument("--no-run", action="store_true", help="skip the real run (device stages only)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a config override by dotted name (repeatable), e.g. raster.max_contributors=64")
    parser.add_argument("--out", type=Path, default=None, help="write the profile as JSON here")
    parser.add_argument("--compare", nargs="+", default=None, metavar="NAME:FIELD=V,...",
                        help="time the step and the tracker of these override sets side by side instead")
    args = parser.parse_args(argv)
    from gsjax.app.runtime.cache import enable_compilation_cache

    enable_compilation_cache()
    from gsjax.config.text import apply_overrides

    sequence, config = open_sequence_for(args.sequence, args.path, args.frame + 1)
    config = apply_overrides(config, dict(item.split("=", 1) for item in args.set))
    if args.compare:
        variants = {}
        for item in args.compare:
            name, _, sets = item.partition(":")
            variants[name] = dict(pair.split("=", 1) for pair in sets.split(",") if pair)
        result = compare(sequence, config, args.frame, args.repeats, variants)
        for name, ms in result.items():
            print(f"{args.sequence} frame {args.frame} {name:12s} step {ms['step']:7.1f} ms  "
                  f"track {ms['track']:7.1f} ms")
        if args.out:
            args.out.write_text(json.dumps(dict(sequence=args.sequence, frame=args.frame, compare=args.compare,
                                                repeats=args.repeats, ms=result), indent=1))
        return 0
    result = dict(sequence=args.sequence, frame=args.frame, overrides=args.set, size=f"{sequence.intrinsics.width}x"
                  f"{sequence.intrinsics.height}", device=jax.devices()[0].device_kind)
    result.update(device_stages(sequence, config, args.frame, args.repeats))
    if not args.no_run:
        with tempfile.TemporaryDirectory() as work:
            result["host_s"] = host_stages(args, Path(work))
    s = result["stages_ms"]
    print(f"{args.sequence} {result['size']}, frame {args.frame}: {result['gaussians']} Gaussians, "
          f"lists {result['mean_list']:.0f} (max {result['longest_list']}), contributors "
          f"{result['contributors_mean']:.1f} (p99 {result['contributors_p99']:.0f}, max {result['contributors_max']}, "
          f"K {result['k']})")
    for name, ms in s.items():
        print(f"  {name:16s} {ms:9.2f} ms")
    print(f"  per iteration (strided or not): tracking {s['track'] / result['tracking_iters']:.2f} ms, mapping "
          f"{s['map'] / result['mapping_iters']:.2f} ms (the stages are shares of the step's profiled op time, "
          f"{result['profiled_op_ms']:.0f} ms per call under the profiler)")
    print(f"  floor: {result['pixel_candidate_pairs']} pixel-candidate alphas fused: {result['floor_alpha_ms']:.2f} ms")
    if "host_s" in result:
        print("  host (s, whole run):", json.dumps(result["host_s"]))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
