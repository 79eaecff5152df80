"""``gsjax run``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from pathlib import Path

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "run",
        help="run SLAM on a sequence and write trajectory, metrics, plots, renders, map and checkpoints",
        description="Run SLAM on a sequence. Any config field can be overridden by its dotted name, e.g. "
        "--tracking.iters 60 --mapping.lr_means 2e-3 --cbknn.params.alpha 0.3 (`gsjax config --reference -` lists "
        "every field).",
        parents=[common.COMMON],
    )
    common.add_sequence_flags(p)
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the previous run in --out (removes gsjax's outputs there, nothing else)")
    p.add_argument("--chunk", type=int, default=8, help="frames per jitted scan chunk (default 8)")
    p.add_argument("--checkpoint-every", type=int, default=8, metavar="N",
                   help="checkpoint after the first chunk that completes N frames since the last checkpoint, and at "
                        "the end (default 8); a checkpoint writes the map and what is new since the previous one")
    p.add_argument("--capacity", type=int, default=None, metavar="N",
                   help="the map's Gaussian slots at the start (default 2 H W, a live camera's 8 H W); a full map "
                        "doubles, re-running the chunk")
    p.add_argument("--eval-every", type=int, default=5, help="render metrics on t=0 and (t+1) %% N == 0")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--tuned", type=Path, default=None, metavar="FILE",
                   help="apply the fields of a tuned.json (gsjax tune) as overrides; --FIELD VALUE on the command "
                        "line wins over it")
    p.add_argument("--viewer", action="store_true",
                   help="show the map live in a browser viewer, updated after each chunk; it stays up after the run "
                        "until Ctrl-C or SIGTERM")
    p.add_argument("--viewer-host", default="127.0.0.1", metavar="HOST",
                   help="the viewer's address (default 127.0.0.1: this machine only)")
    p.add_argument("--viewer-port", type=common.port, default=8080, metavar="PORT",
                   help="the viewer's port (default 8080; the next free one if taken; 0: any free port)")
    p.add_argument("--realtime", action="store_true",
                   help="--dataset realsense: play the recording in real time through the live camera's path (frames "
                        "SLAM cannot keep up with are dropped and counted), as --path live runs a camera")
    p.set_defaults(func=run, accepts_overrides=True)


LIVE_FRAMES = 3000  # --path live stops after this many processed frames unless --max-frames says otherwise


def run_live(args) -> int:
    """``--dataset realsense --path live`` (a camera) or ``--path REC --realtime``: SLAM as frames come."""
    import signal
    import threading

    from gsjax.app.run_folder.layout import check_run_dir
    from gsjax.app.run_folder.outputs import summary_lines
    from gsjax.app.session.camera import LIVE, LiveCamera
    from gsjax.app.session.live import run_live as run_frames
    from gsjax.app.session.runner import RunOptions
    from gsjax.slam.presets import working_downscale

    if args.resume:
        raise common.UserError("--resume: a live camera cannot be re-read; start a new run (--out, --overwrite)")
    for flag, value in (("--stride", args.stride != 1), ("--intrinsics", args.intrinsics is not None),
                        ("--depth-scale", args.depth_scale is not None), ("--groundtruth", args.groundtruth)):
        if value:
            raise common.UserError(f"{flag} does not apply to a live camera (--path live / --realtime)")
    check_run_dir(args.out, overwrite=args.overwrite)
    options = RunOptions(out=args.out, chunk=1, checkpoint_every=args.checkpoint_every, seed=args.seed,
                         overwrite=args.overwrite, eval_every=args.eval_every, capacity=args.capacity, progress=False)
    try:
        camera = LiveCamera(LIVE if str(args.path) == LIVE else args.path)
    except ImportError as error:
        raise common.UserError(str(error)) from None
    factor = args.downscale or working_downscale(args.preset, camera.intrinsics.width)
    config = common.configure(args, camera.intrinsics.width // factor)
    frames = args.max_frames or LIVE_FRAMES
    print(f"gsjax run: {camera.source} ({camera.intrinsics.width}x{camera.intrinsics.height}, downscale {factor}), "
          f"preset {args.preset}, up to {frames} frames; Ctrl-C or SIGTERM stops and writes the outputs", flush=True)
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    describe = dict(dataset=args.dataset, path=str(args.path), preset=args.preset, cbknn=args.cbknn,
                    downscale=factor, overrides=args.overrides, realtime=True)
    view = _live_viewer(args, camera, config, factor, frames) if args.viewer else None
    try:
        metrics = run_frames(camera, config, options, downscale=factor, max_frames=frames, describe=describe,
                             stop=stop, observe=view.update if view else None)
        for line in summary_lines(metrics, args.out):
            print(line)
        if view:
            from gsjax.viewer import wait_for_stop

            view.finished(metrics)
            signal.signal(signal.SIGTERM, signal.default_int_handler)
            print(f"viewer: {view.url} shows the finished run; Ctrl-C or SIGTERM stops it", flush=True)
            print(f"viewer stopped ({wait_for_stop()})", flush=True)
    finally:
        signal.signal(signal.SIGTERM, previous)
        if view:
            view.stop()
    return 0


class _EveryFifth:
    """The live viewer, updated every fifth frame (each update copies the map to the host)."""

    def __init__(self, viewer):
        self.viewer, self.url, self.calls = viewer, viewer.url, 0

    def update(self, state, outputs) -> None:
        self.calls += 1
        if self.calls % 5 == 1:
            self.viewer.update(state, outputs)

    def finished(self, metrics) -> None:
        self.viewer.finished(metrics)

    def stop(self) -> None:
        self.viewer.stop()


def _not_kept(index: int):
    raise IndexError(f"live frame {index} is not kept for the viewer")


def _live_viewer(args, camera, config, factor: int, frames: int):
    import numpy as np

    from gsjax.data.sequence import Sequence
    from gsjax.viewer.live import LiveViewer
    from gsjax.viewer.scene import check_listen_address

    check_listen_address(args.viewer_host)
    k = camera.intrinsics if factor == 1 else camera.intrinsics.downscaled(factor)
    frames_so_far = Sequence(name=str(args.path), intrinsics=k, timestamps=np.arange(frames, dtype=np.float64),
                             c2w=np.tile(np.eye(4), (frames, 1, 1)), pose_valid=np.zeros(frames, bool),
                             read_rgbd=_not_kept)
    view = _EveryFifth(LiveViewer(frames_so_far, config, host=args.viewer_host, port=args.viewer_port))
    print(f"viewer: {view.url} (updated every fifth frame)", flush=True)
    return view


def run(args) -> int:
    if args.tuned is not None:
        from gsjax.app.tune import read_tuned

        args.overrides = {**{name: repr(value) for name, value in read_tuned(args.tuned).items()}, **args.overrides}
    if args.dataset == "realsense" and (str(args.path) == "live" or args.realtime):
        return run_live(args)
    if args.realtime:
        raise common.UserError("--realtime plays a RealSense recording as a camera: --dataset realsense --path REC")
    from gsjax.app.run_folder.layout import check_run_dir
    from gsjax.app.run_folder.outputs import summary_lines
    from gsjax.app.session.runner import RunOptions, run_slam
    from gsjax.slam.presets import PRESET_WIDTH

    common.quiet_logs()

    common.configure(args)  # bad overrides are reported before any data is read
    if args.viewer:
        from gsjax.viewer.scene import check_listen_address

        check_listen_address(args.viewer_host)
    options = RunOptions(out=args.out, chunk=args.chunk, checkpoint_every=args.checkpoint_every, seed=args.seed,
                         resume=args.resume, overwrite=args.overwrite, eval_every=args.eval_every,
                         capacity=args.capacity, progress=not args.no_progress)
    check_run_dir(args.out, resume=args.resume, overwrite=args.overwrite)  # before reading any data
    (sequence, factor), input_warnings = common.dataset_warnings(lambda: common.open_run_sequence(args))
    describe = common.describe_run(args, sequence, factor)
    width = sequence.intrinsics.width
    config = common.configure(args, width)
    print(f"gsjax run: {sequence!r}, preset {args.preset}, CB-KNN {args.cbknn}, downscale {factor} -> {args.out}",
          flush=True)
    scale = width / PRESET_WIDTH[args.preset]
    print(f"working resolution {width}x{sequence.intrinsics.height}: pixel settings at {scale:g}x the preset's "
          f"{PRESET_WIDTH[args.preset]} px (mapping.overlap_margin {config.mapping.overlap_margin:g} px, "
          f"cbknn.params.alpha {config.cbknn.params.alpha:g}; mapping.prune_scale_ratio "
          f"{config.mapping.prune_scale_ratio:g}, at {1 / scale:g}x the preset's pixel footprint)", flush=True)
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
