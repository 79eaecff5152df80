"""``gsjax run``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "run",
        help="run SLAM on a sequence and write trajectory, metrics, plots, renders, map and checkpoints",
        description="Run SLAM on a sequence. Any config field can be overridden by its dotted name, e.g. "
        "--tracking.iters 60 --mapping.lr_means 2e-3 --cbknn.params.alpha 0.3 (see gsjax/slam/config.py).",
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
    p.add_argument("--eval-every", type=int, default=5, help="render metrics on t=0 and (t+1) %% N == 0")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--viewer", action="store_true",
                   help="show the map live in a browser viewer, updated after each chunk; it stays up after the run "
                        "until Ctrl-C or SIGTERM")
    p.add_argument("--viewer-host", default="127.0.0.1", metavar="HOST",
                   help="the viewer's address (default 127.0.0.1: this machine only)")
    p.add_argument("--viewer-port", type=common.port, default=8080, metavar="PORT",
                   help="the viewer's port (default 8080; the next free one if taken; 0: any free port)")
    p.set_defaults(func=run, accepts_overrides=True)


def run(args) -> int:
    from gsjax.app.run_dir import check_run_dir
    from gsjax.app.run_outputs import summary_lines
    from gsjax.app.runner import RunOptions, run_slam
    from gsjax.slam.presets import PRESET_WIDTH

    common.quiet_logs()

    common.configure(args)  # bad overrides are reported before any data is read
    if args.viewer:
        from gsjax.viewer.scene import check_listen_address

        check_listen_address(args.viewer_host)
    options = RunOptions(out=args.out, chunk=args.chunk, checkpoint_every=args.checkpoint_every, seed=args.seed,
                         resume=args.resume,
                         overwrite=args.overwrite, eval_every=args.eval_every, progress=not args.no_progress)
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
