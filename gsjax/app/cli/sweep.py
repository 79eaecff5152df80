"""``gsjax sweep``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "sweep",
        help="a grid of configs on one sequence as one vmapped program (sweep.csv, sweep.md, sweep.png, runs/NNN)",
        description="Run a grid of configs on one sequence. --grid FIELD=V1,V2 sets a config field by its dotted name "
        "(e.g. --grid cbknn.params.alpha=0.1,0.2 --grid cbknn.params.k0=4,8); the grid is the product of the axes "
        "times --seeds run seeds. Configs that differ in traced fields run as one compiled program (jax.vmap over "
        "the stacked configs, the batch sharded over the devices); a static field gives one program per value. "
        "Other config fields can be overridden as in gsjax run (--tracking.iters 60).",
        parents=[common.COMMON],
    )
    common.add_sequence_flags(p)
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
    p.add_argument("--resume", action="store_true",
                   help="continue the sweep in --out: its finished configs (runs/NNN with a metrics.json) stay as "
                        "they are, the others run again, and the tables cover them all")
    p.add_argument("--chunk", type=int, default=8, help="frames per jitted scan chunk (default 8)")
    p.add_argument("--eval-every", type=int, default=5, help="render metrics on t=0 and (t+1) %% N == 0")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run, accepts_overrides=True)


def run(args) -> int:
    from gsjax.app.run_folder.layout import check_run_dir
    from gsjax.app.sweep.devices import (
        default_cpu_devices,
        maybe_initialize_distributed,
        request_cpu_devices,
    )
    from gsjax.app.sweep.grid import (
        SweepOptions,
        batch_size,
        expand_grid,
        parse_grid,
        run_sweep,
    )
    from gsjax.io.run_folder import SWEEP_FILES

    common.quiet_logs()
    if args.seeds < 1:
        raise common.UserError(f"--seeds must be >= 1, got {args.seeds}")
    axes = [parse_grid(text) for text in args.grid]

    if args.devices is not None and args.devices < 1:
        raise common.UserError(f"--devices must be >= 1, got {args.devices}")
    # Bad overrides and grid values are reported before reading data.
    configs = len(expand_grid(common.configure(args), axes, [args.seed])) * args.seeds
    options = SweepOptions(out=args.out, chunk=args.chunk, batch=args.batch, vmap_width=args.vmap_width,
                           eval_every=args.eval_every,
                           progress=not args.no_progress, overwrite=args.overwrite, resume=args.resume)
    check_run_dir(args.out, resume=args.resume, overwrite=args.overwrite, outputs=SWEEP_FILES)
    request_cpu_devices(args.devices or default_cpu_devices(batch_size(args.batch, configs)))
    maybe_initialize_distributed()
    (sequence, factor), input_warnings = common.dataset_warnings(lambda: common.open_run_sequence(args))
    describe = common.describe_run(args, sequence, factor)
    seeds = list(range(args.seed, args.seed + args.seeds))
    config = common.configure(args, sequence.intrinsics.width)
    rows = run_sweep(sequence, config, axes, seeds, options, describe=describe, input_warnings=tuple(input_warnings))
    import jax

    if jax.process_index() != 0:  # a multi-host sweep's other processes wrote nothing
        return 0
    best = min((r for r in rows if r["ate_rmse_cm"] is not None), key=lambda r: r["ate_rmse_cm"], default=None)
    if best is not None:
        chosen = ", ".join(f"{k}={best[k]}" for k in (a.field for a in axes)) or "the base config"
        print(f"lowest ATE {best['ate_rmse_cm']:.3f} cm: {chosen}, seed {best['seed']} ({best['run']})")
    print(f"outputs in {args.out.resolve()}: sweep.csv sweep.md sweep.png sweep.json runs/")
    return 0
