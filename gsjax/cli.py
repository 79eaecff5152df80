"""The ``gsjax`` command line: the imperative shell around the pure core.

Each subcommand has an ``_add_<name>(subparsers)`` that declares its flags and a ``_cmd_<name>(args)`` that runs
it. Heavy imports happen inside the command functions so ``gsjax --help`` stays fast. User errors (bad paths,
bad values, bad data) are reported as one line ``gsjax <cmd>: error: ...`` with exit status 2, never a stack
trace (``--debug`` shows it); what gsjax handles in a defined way is printed as ``warning: ...``.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

from gsjax.names import CBKNN_MODES, DATASETS, PRESETS


class UserError(Exception):
    """An error caused by the user's input; printed without a traceback."""


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``gsjax run: error: argument --x: ...``), like every other error."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _dataset_warnings(open_fn):
    """Call ``open_fn()``; print each distinct DatasetWarning it raised as one ``warning: ...`` line on stderr (other
    warnings as Python shows them) -> (its result, the DatasetWarning messages). Distinct: ``gsjax run`` lists a
    dataset twice (once to learn its image size)."""
    from gsjax.data import DatasetWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        result = open_fn()
    messages = []
    for item in caught:
        if issubclass(item.category, DatasetWarning):
            if str(item.message) in messages:
                continue
            messages.append(str(item.message))
            print(f"warning: {item.message}", file=sys.stderr, flush=True)
        else:
            warnings.showwarning(item.message, item.category, item.filename, item.lineno)
    return result, messages




# Options every subcommand takes.
COMMON = argparse.ArgumentParser(add_help=False)
COMMON.add_argument("--debug", action="store_true", help="show the full traceback of an error")


def _add_eval(sub) -> None:
    p = sub.add_parser("eval", help="trajectory metrics (ATE, RPE) of an estimate against ground truth",
                       parents=[COMMON])
    p.add_argument("--est", type=Path, required=True, help="estimated trajectory, TUM format (camera-to-world)")
    p.add_argument("--gt", type=Path, required=True,
                   help="ground truth: a TUM trajectory file, or a dataset directory (with --dataset)")
    p.add_argument("--dataset", choices=DATASETS, default=None,
                   help="layout of the --gt directory; its GT poses are taken at the dataset's frame timestamps "
                        "(the frame numbers for replica, scannet and 7scenes, which have no timestamps)")
    p.add_argument("--out", type=Path, default=None, help="metrics JSON (default: <est without suffix>.metrics.json)")
    p.add_argument("--scale", action="store_true", help="also align the scale (similarity / Umeyama)")
    p.add_argument("--max-dt", type=float, default=0.02, help="timestamp association tolerance in s (default 0.02)")
    p.add_argument("--plots", type=Path, default=None, help="also write trajectory and error plots into this directory")
    p.set_defaults(func=_cmd_eval)


def _read_ground_truth(gt: Path, dataset: str | None):
    """(timestamps [M] s, c2w [M, 4, 4] float64, valid [M] bool or None) from a TUM file or a dataset directory."""
    if gt.is_dir():
        if dataset is None:
            raise UserError(
                f"--gt {gt} is a directory: --gt DIR needs --dataset {{{','.join(DATASETS)}}} "
                f"(the layout is not guessed), or give a TUM trajectory file"
            )
        from gsjax.data import open_sequence

        return _dataset_warnings(lambda: open_sequence(dataset, gt).gt_trajectory())[0]  # reads no image
    if not gt.is_file():
        raise UserError(f"--gt {gt}: no such file")
    if dataset is not None:
        raise UserError(f"--dataset {dataset} needs --gt DIR, a dataset directory; {gt} is a file")
    from gsjax.io.trajectory import read_tum_trajectory

    return (*read_tum_trajectory(gt), None)


def _cmd_eval(args) -> int:
    import numpy as np

    from gsjax.eval.association import associate_timestamps
    from gsjax.eval.trajectory import ate_rmse_c2w, evaluate_trajectory
    from gsjax.io.atomic import atomic_write_json
    from gsjax.io.trajectory import read_tum_trajectory

    if not args.est.is_file():
        raise UserError(f"--est {args.est}: no such file")
    if not (np.isfinite(args.max_dt) and args.max_dt >= 0):
        raise UserError(f"--max-dt must be a number >= 0, got {args.max_dt}")
    gt_t, gt_c2w, gt_valid = _read_ground_truth(args.gt, args.dataset)
    est_t, est_c2w = read_tum_trajectory(args.est)
    metrics = evaluate_trajectory(
        est_t, est_c2w, gt_t, gt_c2w, gt_valid=gt_valid, max_dt=args.max_dt, with_scale=args.scale
    )
    sources = {"est": str(args.est), "gt": str(args.gt)}
    if args.dataset is not None:
        sources["gt_dataset"] = args.dataset
    metrics = {**sources, **metrics}
    out = args.out if args.out is not None else args.est.with_suffix(".metrics.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out, metrics)

    for key, value in metrics.items():
        if isinstance(value, float):
            print(f"{key:26s} {value:.6g}")
        elif isinstance(value, (int, bool)) or value is None:
            print(f"{key:26s} {value}")
    print(f"wrote {out}")

    if args.plots is not None:
        from gsjax.io.plots import plot_errors_over_time, plot_trajectory_top_view

        est_idx, gt_idx = associate_timestamps(est_t, gt_t, args.max_dt)
        used = None if gt_valid is None else gt_valid[gt_idx]
        ate = ate_rmse_c2w(est_c2w[est_idx], gt_c2w[gt_idx], used, with_scale=args.scale)
        est_aligned = ate.alignment.apply_points(est_c2w[est_idx][ate.used, :3, 3])
        args.plots.mkdir(parents=True, exist_ok=True)
        title = f"ATE RMSE (c2w) {100 * ate.value_m:.2f} cm"
        for path in (
            plot_trajectory_top_view(args.plots / "trajectory_top.png", est_aligned, gt_c2w[gt_idx][ate.used, :3, 3],
                                     title=title),
            plot_errors_over_time(args.plots / "ate_over_time.png", est_t[est_idx][ate.used],
                                  {"ATE (cm)": 100 * ate.errors_m}, ylabel="ATE (cm)", title=title),
        ):
            print(f"wrote {path}")
    return 0


def _add_synth(sub) -> None:
    p = sub.add_parser("synth", help="render a synthetic RGB-D sequence and write it in the TUM RGB-D layout",
                       parents=[COMMON])
    p.add_argument("--out", type=Path, required=True, help="output directory (must not exist or be empty)")
    p.add_argument("--frames", type=int, default=60, help="number of frames (default 60)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--noise", action="store_true", help="add Kinect-like sensor noise, holes and blur")
    p.set_defaults(func=_cmd_synth)


def _cmd_synth(args) -> int:
    from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
    from gsjax.data.tum import write_tum

    if args.frames < 1:
        raise UserError(f"--frames must be >= 1, got {args.frames}")
    if args.out.exists() and (not args.out.is_dir() or any(args.out.iterdir())):
        raise UserError(f"--out {args.out} already exists and is not an empty directory; refusing to overwrite")
    config = SyntheticConfig(num_frames=args.frames, seed=args.seed)
    if args.noise:
        config = config.with_sensor_noise()
    write_tum(synthetic_sequence(config), args.out)
    print(f"wrote {args.frames} frames ({config.width}x{config.height}) in the TUM layout to {args.out}")
    return 0


SYNTHETIC_FRAMES = 30  # frames of `gsjax run --dataset synthetic` unless --max-frames says otherwise


def _add_run(sub) -> None:
    p = sub.add_parser(
        "run",
        help="run SLAM on a sequence and write trajectory, metrics, plots, renders, map and checkpoints",
        description="Run SLAM on a sequence. Any config field can be overridden by its dotted name, e.g. "
        "--tracking.iters 60 --mapping.lr_means 2e-3 --cbknn.params.alpha 0.3 (see gsjax/slam/config.py).",
        parents=[COMMON],
    )
    _add_sequence_flags(p)
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the previous run in --out (removes gsjax's outputs there, nothing else)")
    p.add_argument("--chunk", type=int, default=8, help="frames per jitted scan chunk (default 8)")
    p.add_argument("--checkpoint-every", type=int, default=8, metavar="N",
                   help="checkpoint after the first chunk that completes N frames since the last checkpoint, and at "
                        "the end (default 8); a checkpoint writes the map and what is new since the previous one")
    p.add_argument("--eval-every", type=int, default=5, help="render metrics on t=0 and (t+1) %% N == 0")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--viewer", action="store_true",
                   help="show the map live in a browser viewer, updated after each chunk; it stays up after the run "
                        "until Ctrl-C or SIGTERM")
    p.add_argument("--viewer-host", default="127.0.0.1", metavar="HOST",
                   help="the viewer's address (default 127.0.0.1: this machine only)")
    p.add_argument("--viewer-port", type=_port, default=8080, metavar="PORT",
                   help="the viewer's port (default 8080; the next free one if taken; 0: any free port)")
    p.set_defaults(func=_cmd_run, accepts_overrides=True)


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port number 0-65535, got {text!r}")
    return value


def _add_sequence_flags(p) -> None:
    """The flags that choose the sequence, its camera and the config (shared by run, sweep and landscape)."""
    p.add_argument("--dataset", choices=DATASETS + ("synthetic",), required=True)
    p.add_argument("--path", type=Path, default=None, help="dataset directory (not needed for synthetic)")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--preset", choices=PRESETS, default="cpu", help="configuration preset (default cpu)")
    p.add_argument("--cbknn", choices=CBKNN_MODES, default="off", help="CB-KNN mode (default off = SplaTAM)")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--stride", type=int, default=1, help="use every N-th frame (faster motion)")
    p.add_argument("--downscale", type=int, default=None,
                   help="integer image reduction (default: to about 80 px wide for the cpu preset, else 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--intrinsics", type=_pinhole, default=None, metavar="FX,FY,CX,CY",
                   help="the camera in pixels at the stored image size, overriding the dataset's own")
    p.add_argument("--depth-scale", type=_depth_scale, default=None, metavar="S",
                   help="stored depth units per metre, overriding the dataset's (TUM 5000, 7-Scenes 1000)")
    p.add_argument("--synthetic-noise", action="store_true",
                   help="synthetic dataset only: Kinect-like sensor effects (depth noise, holes, colour noise, blur)")


def _pinhole(text: str) -> tuple[float, float, float, float]:
    """``FX,FY,CX,CY`` -> four floats (fx, fy > 0); argparse reports the error naming --intrinsics."""
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(f"expected FX,FY,CX,CY: four numbers in pixels, got {text!r}")
    if values[0] <= 0 or values[1] <= 0:
        raise argparse.ArgumentTypeError(f"the focal lengths FX and FY must be > 0, got {text!r}")
    return values


def _depth_scale(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a number > 0 (stored depth units per metre), got {text!r}")
    return value


def _parse_overrides(tokens: list[str]) -> dict[str, str]:
    """``--a.b value`` / ``--a.b=value`` pairs -> {"a.b": "value"}."""
    overrides, i = {}, 0
    while i < len(tokens):
        token = tokens[i]
        if not token.startswith("--") or "." not in token:
            raise UserError(f"unrecognised argument {token!r} (config overrides look like --tracking.iters 60)")
        if "=" in token:
            name, value = token[2:].split("=", 1)
            i += 1
        else:
            if i + 1 >= len(tokens):
                raise UserError(f"{token} needs a value")
            name, value = token[2:], tokens[i + 1]
            i += 2
        overrides[name] = value
    return overrides


def _open_run_sequence(args):
    """The sequence to run on, with the downscale the preset implies."""
    from gsjax.slam.presets import working_downscale

    if args.stride < 1 or (args.max_frames is not None and args.max_frames < 1):
        raise UserError("--stride and --max-frames must be >= 1")
    if args.downscale is not None and args.downscale < 1:
        raise UserError(f"--downscale must be >= 1, got {args.downscale}")
    if args.dataset == "synthetic":
        for flag, value in (("--intrinsics", args.intrinsics), ("--depth-scale", args.depth_scale)):
            if value is not None:
                raise UserError(f"{flag} applies to datasets read from disk; the synthetic scene has its own camera")
        from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence

        base = SyntheticConfig()
        factor = args.downscale or working_downscale(args.preset, base.width)
        if factor < 1 or base.width % factor or base.height % factor:
            raise UserError(f"--downscale {factor} must divide the synthetic {base.width}x{base.height} image")
        frames = args.max_frames or SYNTHETIC_FRAMES
        config = SyntheticConfig(width=base.width // factor, height=base.height // factor, num_frames=frames,
                                 speed=float(args.stride), seed=args.seed)
        if args.synthetic_noise:
            config = config.with_sensor_noise()
        return synthetic_sequence(config), factor
    from gsjax.data import open_sequence

    if args.synthetic_noise:
        raise UserError("--synthetic-noise applies to --dataset synthetic only")
    if args.path is None:
        raise UserError(f"--dataset {args.dataset} needs --path DIR")
    if not args.path.is_dir():
        raise UserError(f"--path {args.path}: no such directory")
    camera = dict(intrinsics=args.intrinsics, depth_scale=args.depth_scale)
    probe = open_sequence(args.dataset, args.path, max_frames=1, **camera)
    native = probe.intrinsics
    if args.intrinsics is not None and not (0 <= args.intrinsics[2] <= native.width
                                            and 0 <= args.intrinsics[3] <= native.height):
        raise UserError(f"--intrinsics: the principal point ({args.intrinsics[2]:g}, {args.intrinsics[3]:g}) lies "
                        f"outside the {native.width}x{native.height} images; give the values in pixels at the stored "
                        "image size")
    factor = args.downscale or working_downscale(args.preset, native.width)
    if factor > min(native.width, native.height):
        raise UserError(f"--downscale {factor} leaves no pixel of the {native.width}x{native.height} images")
    sequence = open_sequence(args.dataset, args.path, max_frames=args.max_frames, stride=args.stride,
                             downscale=factor, **camera)
    return sequence, factor


def _configure(args, width: int | None = None):
    """The preset at the working ``width`` with the CB-KNN mode, then the command line's overrides as given."""
    from gsjax.config_text import apply_overrides
    from gsjax.slam.presets import preset, with_cbknn_mode

    return apply_overrides(with_cbknn_mode(preset(args.preset, width), args.cbknn), args.overrides)


def _describe(args, sequence, factor: int) -> dict:
    """What a run, sweep or landscape records about its input (config.json, metrics.json, sweep.json, ...)."""
    return dict(dataset=args.dataset, path=str(args.path) if args.path else None, preset=args.preset,
                cbknn=args.cbknn, downscale=factor, stride=args.stride, overrides=args.overrides,
                intrinsics=list(args.intrinsics) if args.intrinsics else None, depth_scale=args.depth_scale,
                sequence=sequence.name)


def _cmd_run(args) -> int:
    from gsjax.io.run_dir import check_run_dir
    from gsjax.run_outputs import summary_lines
    from gsjax.runner import RunOptions, run_slam
    from gsjax.slam.presets import PRESET_WIDTH

    _quiet_logs()

    _configure(args)  # bad overrides are reported before any data is read
    if args.viewer:
        from gsjax.viewer.scene import check_listen_address

        check_listen_address(args.viewer_host)
    options = RunOptions(out=args.out, chunk=args.chunk, checkpoint_every=args.checkpoint_every, seed=args.seed,
                         resume=args.resume,
                         overwrite=args.overwrite, eval_every=args.eval_every, progress=not args.no_progress)
    check_run_dir(args.out, resume=args.resume, overwrite=args.overwrite)  # before reading any data
    (sequence, factor), input_warnings = _dataset_warnings(lambda: _open_run_sequence(args))
    describe = _describe(args, sequence, factor)
    width = sequence.intrinsics.width
    config = _configure(args, width)
    print(f"gsjax run: {sequence!r}, preset {args.preset}, CB-KNN {args.cbknn}, downscale {factor} -> {args.out}",
          flush=True)
    scale = width / PRESET_WIDTH[args.preset]
    print(f"working resolution {width}x{sequence.intrinsics.height}: pixel settings at {scale:g}x the preset's "
          f"{PRESET_WIDTH[args.preset]} px (mapping.overlap_margin {config.mapping.overlap_margin:g} px, "
          f"cbknn.params.alpha {config.cbknn.params.alpha:g})", flush=True)
    live = None
    if args.viewer:
        import signal

        from gsjax.viewer.live import LiveViewer

        live = LiveViewer(sequence, config, host=args.viewer_host, port=args.viewer_port)
        signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM stops the run like Ctrl-C
        print(f"viewer: {live.url} (updated after each chunk of {args.chunk} frames; the map as points until the "
              "run is done, see 'map as')", flush=True)
    try:
        metrics = run_slam(sequence, config, options, describe=describe, input_warnings=tuple(input_warnings),
                           observe=live.update if live else None)
        for line in summary_lines(metrics, args.out):
            print(line)
        if live:
            from gsjax.viewer import wait_for_stop

            live.finished(metrics)
            print(f"viewer: {live.url} shows the finished run; Ctrl-C or SIGTERM stops it", flush=True)
            print(f"viewer stopped ({wait_for_stop()})", flush=True)
    finally:
        if live:
            live.stop()
    return 0


def _add_report(sub) -> None:
    p = sub.add_parser(
        "report", help="the self-contained HTML report of a run, or of several runs side by side",
        description="Write report.html: metrics, the trajectory against ground truth, ATE and RPE over time, renders "
        "against inputs with error maps, PSNR per frame, Gaussian count, timings, CB-KNN's K and rho maps, warnings "
        "and the config. One RUN: RUN/report.html (gsjax run writes it too). A sweep's directory: its runs side by "
        "side in SWEEP/report.html. Several RUNs: side by side in ./report.html.",
        parents=[COMMON])
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="a gsjax run's (or sweep's) output directory")
    p.add_argument("--out", type=Path, default=None,
                   help="the page to write (default: see above; an existing file is replaced only if it is a gsjax "
                        "report)")
    p.set_defaults(func=_cmd_report)


def _cmd_report(args) -> int:
    from gsjax.report import write_report

    path = write_report(args.runs, args.out)
    print(f"wrote {path}")
    return 0


def _add_view(sub) -> None:
    p = sub.add_parser(
        "view", help="a browser viewer of a run: the map as splats, trajectories, keyframes, a frame slider",
        description="Serve the finished run in RUN_DIR to a browser (viser): the Gaussian map as splats, the "
        "estimated and ground-truth trajectories with keyframe frustums, the input and rendered images of the "
        "selected keyframe and a frame slider. Stops on Ctrl-C (SIGINT) or SIGTERM.",
        parents=[COMMON])
    p.add_argument("run", type=Path, metavar="RUN_DIR", help="a gsjax run's output directory")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=_port, default=8080,
                   help="port (default 8080; the next free one if taken; 0: any free port)")
    p.set_defaults(func=_cmd_view)


def _cmd_view(args) -> int:
    from gsjax.viewer import open_run, wait_for_stop

    _quiet_logs()
    viewer = open_run(args.run, host=args.host, port=args.port)
    try:
        print(f"viewer: {viewer.url} shows {args.run}; Ctrl-C or SIGTERM stops it", flush=True)
        print(f"viewer stopped ({wait_for_stop()})", flush=True)
    finally:
        viewer.stop()
    return 0


def _backends(text: str) -> list[str]:
    names = [x.strip() for x in text.split(",") if x.strip()]
    bad = [x for x in names if x not in ("xla", "pallas")]
    if not names or bad:
        raise argparse.ArgumentTypeError(f"{text!r}: a comma-separated list of xla, pallas")
    return names


def _sizes(text: str) -> list[tuple[int, int]]:
    from gsjax.bench import parse_size

    try:
        return [parse_size(x.strip()) for x in text.split(",") if x.strip()]
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).removeprefix("--sizes: ")) from None


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive integer")
    return value


def _add_bench(sub) -> None:
    p = sub.add_parser(
        "bench", help="rasterizer and tracking-iteration speed and memory per backend on this device",
        description="Time the render forward, forward+backward and one tracking iteration (median after a warm-up, "
        "compile time apart), ns per pixel x candidate and the peak memory of a tracking iteration, for each "
        "backend and image size, on a SplaTAM-density map of a synthetic room. Prints a table and writes JSON. "
        "On a CPU the pallas backend runs in interpret mode (slow: a correctness aid, not a speed).",
        parents=[COMMON])
    p.add_argument("--backend", type=_backends, default=None, metavar="LIST",
                   help="comma-separated backends: xla, pallas (default: xla,pallas on a GPU, xla elsewhere)")
    p.add_argument("--sizes", type=_sizes, default=[(640, 480), (1200, 680)], metavar="WxH,...",
                   help="image sizes (default 640x480,1200x680)")
    p.add_argument("--gaussians", type=_positive, default=None, metavar="N",
                   help="active Gaussians in the map (default: about one per pixel, SplaTAM's density)")
    p.add_argument("--k", type=_positive, default=96, help="contributor slots per pixel (default 96, SLAM's)")
    p.add_argument("--repeats", type=_positive, default=5, help="timed runs after the warm-up (default 5)")
    p.add_argument("--out", type=Path, default=Path("bench.json"), help="the JSON to write (default bench.json)")
    p.set_defaults(func=_cmd_bench)


def _cmd_bench(args) -> int:
    from gsjax.bench import run_bench
    from gsjax.io.atomic import atomic_write_json
    from gsjax.raster import pallas

    if args.out.is_dir():
        raise UserError(f"--out {args.out} is a directory; give the JSON file to write")
    backends = args.backend or (["xla", "pallas"] if pallas.on_gpu() else ["xla"])
    result = run_bench(backends, args.sizes, args.gaussians, args.repeats, args.k,
                       log=lambda line: print(line, flush=True))
    print(f"wrote {atomic_write_json(args.out, result)}")
    return 0


def _add_sweep(sub) -> None:
    p = sub.add_parser(
        "sweep",
        help="a grid of configs on one sequence as one vmapped program (sweep.csv, sweep.md, sweep.png, runs/NNN)",
        description="Run a grid of configs on one sequence. --grid FIELD=V1,V2 sets a config field by its dotted name "
        "(e.g. --grid cbknn.params.alpha=0.1,0.2 --grid cbknn.params.k0=4,8); the grid is the product of the axes "
        "times --seeds run seeds. Configs that differ in traced fields run as one compiled program (jax.vmap over "
        "the stacked configs, the batch sharded over the devices); a static field gives one program per value. "
        "Other config fields can be overridden as in gsjax run (--tracking.iters 60).",
        parents=[COMMON],
    )
    _add_sequence_flags(p)
    p.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2",
                   help="a grid axis: a config field's dotted name and its values (repeat for more axes)")
    p.add_argument("--seeds", type=int, default=1, help="run seeds per config: --seed .. --seed + N - 1 (default 1)")
    p.add_argument("--batch", type=int, default=None,
                   help="configs run at a time, to bound memory (default: all configs of a program at once)")
    p.add_argument("--vmap-width", type=int, default=None, metavar="V",
                   help="configs stacked into one vmapped program call, sharded over the devices (default: 1 on "
                        "CPU, where the vmapped scan is slower per config, 64 on accelerators)")
    p.add_argument("--devices", type=int, default=None, metavar="N",
                   help="CPU devices the configs are spread over, running at the same time (default: one per two "
                        "cores, as one SLAM program keeps about 1.3 cores busy, at most the configs of a batch; "
                        "ignored when XLA_FLAGS forces a count, and on accelerators)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the previous sweep in --out (removes gsjax's sweep outputs there, nothing else)")
    p.add_argument("--chunk", type=int, default=8, help="frames per jitted scan chunk (default 8)")
    p.add_argument("--eval-every", type=int, default=5, help="render metrics on t=0 and (t+1) %% N == 0")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep, accepts_overrides=True)


def _cmd_sweep(args) -> int:
    from gsjax.io.run_dir import SWEEP_OUTPUTS, check_run_dir
    from gsjax.sweep import SweepOptions, batch_size, expand_grid, parse_grid, run_sweep
    from gsjax.sweep_devices import default_cpu_devices, maybe_initialize_distributed, request_cpu_devices

    _quiet_logs()
    if args.seeds < 1:
        raise UserError(f"--seeds must be >= 1, got {args.seeds}")
    axes = [parse_grid(text) for text in args.grid]

    if args.devices is not None and args.devices < 1:
        raise UserError(f"--devices must be >= 1, got {args.devices}")
    # Bad overrides and grid values are reported before reading data.
    configs = len(expand_grid(_configure(args), axes, [args.seed])) * args.seeds
    options = SweepOptions(out=args.out, chunk=args.chunk, batch=args.batch, vmap_width=args.vmap_width,
                           eval_every=args.eval_every,
                           progress=not args.no_progress, overwrite=args.overwrite)
    check_run_dir(args.out, overwrite=args.overwrite, outputs=SWEEP_OUTPUTS)
    request_cpu_devices(args.devices or default_cpu_devices(batch_size(args.batch, configs)))
    maybe_initialize_distributed()
    (sequence, factor), input_warnings = _dataset_warnings(lambda: _open_run_sequence(args))
    describe = _describe(args, sequence, factor)
    seeds = list(range(args.seed, args.seed + args.seeds))
    rows = run_sweep(sequence, _configure(args, sequence.intrinsics.width), axes, seeds, options, describe=describe,
                     input_warnings=tuple(input_warnings))
    import jax

    if jax.process_index() != 0:  # a multi-host sweep's other processes wrote nothing
        return 0
    best = min((r for r in rows if r["ate_rmse_cm"] is not None), key=lambda r: r["ate_rmse_cm"], default=None)
    if best is not None:
        chosen = ", ".join(f"{k}={best[k]}" for k in (a.field for a in axes)) or "the base config"
        print(f"lowest ATE {best['ate_rmse_cm']:.3f} cm: {chosen}, seed {best['seed']} ({best['run']})")
    print(f"outputs in {args.out.resolve()}: sweep.csv sweep.md sweep.png sweep.json runs/")
    return 0


def _add_landscape(sub) -> None:
    p = sub.add_parser(
        "landscape",
        help="frame T's tracking loss and its jax.grad along pose perturbations, CB-KNN off vs paper, with basins",
        description="Build the map from frames 0..T-1 (SLAM, or --map-from gt), then evaluate frame T's tracking "
        "loss (exactly the tracker's) under left perturbations of the reference pose (frame T's ground truth, else "
        "its tracked pose) along each axis (tx ty tz in cm, rx ry rz in degrees), with jax.grad at every grid point, "
        "for CB-KNN off and paper; and the basin: how far off the tracker still returns to within 0.5 cm / 0.5 deg. "
        "Writes landscape.json and landscape.png.",
        parents=[COMMON],
    )
    _add_sequence_flags(p)
    p.add_argument("--frame", type=int, required=True, help="the frame T whose tracking loss is studied (>= 1)")
    p.add_argument("--axes", default="tx,ry", help="comma-separated axes among tx,ty,tz,rx,ry,rz (default tx,ry)")
    p.add_argument("--extent-cm", type=float, default=4.0, help="translation grid half-width (cm, default 4)")
    p.add_argument("--extent-deg", type=float, default=4.0, help="rotation grid half-width (degrees, default 4)")
    p.add_argument("--steps", type=int, default=21, help="grid points per axis (default 21)")
    p.add_argument("--map-from", choices=("slam", "gt"), default="slam",
                   help="build the map by SLAM (default) or at the ground-truth poses")
    p.add_argument("--overwrite", action="store_true", help="replace a previous landscape in --out")
    p.add_argument("--chunk", type=int, default=8, help="frames per jitted scan chunk while mapping (default 8)")
    p.set_defaults(func=_cmd_landscape, accepts_overrides=True)


def _cmd_landscape(args) -> int:
    from gsjax.io.run_dir import LANDSCAPE_OUTPUTS, check_run_dir
    from gsjax.landscape import LandscapeOptions, run_landscape

    _quiet_logs()
    _configure(args)  # bad overrides are reported before any data is read
    options = LandscapeOptions(out=args.out, frame=args.frame, axes=tuple(a.strip() for a in args.axes.split(",")),
                               extent_cm=args.extent_cm, extent_deg=args.extent_deg, steps=args.steps,
                               map_from=args.map_from, seed=args.seed, chunk=args.chunk, overwrite=args.overwrite)
    check_run_dir(args.out, overwrite=args.overwrite, outputs=LANDSCAPE_OUTPUTS)
    if args.max_frames is None:
        args.max_frames = args.frame + 1  # frames past T are not read
    (sequence, factor), _ = _dataset_warnings(lambda: _open_run_sequence(args))
    describe = _describe(args, sequence, factor)
    document = run_landscape(sequence, _configure(args, sequence.intrinsics.width), options, describe=describe)
    for axis, entry in document["axes"].items():
        print(f"{axis}: basin off {entry['off']['basin']:g} {entry['unit']}, paper {entry['paper']['basin']:g} "
              f"{entry['unit']}")
    print(f"outputs in {args.out.resolve()}: landscape.json landscape.png")
    return 0


def _quiet_logs() -> None:
    import logging

    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    logging.getLogger("gsjax").setLevel(logging.INFO)
    for noisy in ("absl", "orbax", "jax"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="gsjax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_run, _add_sweep, _add_landscape, _add_report, _add_view, _add_bench, _add_eval, _add_synth):
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:  # a usage error (or --help) exits from argparse; in-process callers get its status back
        args, extra = parser.parse_known_args(argv)
        if extra and not getattr(args, "accepts_overrides", False):
            parser.error(f"unrecognised arguments: {' '.join(extra)}")
    except SystemExit as exit_:
        return int(exit_.code or 0)
    from gsjax.compilation_cache import enable_compilation_cache

    enable_compilation_cache()
    try:
        args.overrides = _parse_overrides(extra)
        return int(args.func(args) or 0)
    except (UserError, ValueError, OSError) as err:  # DatasetError and RunDirError are ValueErrors
        if args.debug:
            raise
        print(f"gsjax {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if args.debug:
            raise
        again = " (continue it with --resume)" if args.command == "run" else ""
        print(f"gsjax {args.command}: interrupted{again}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
