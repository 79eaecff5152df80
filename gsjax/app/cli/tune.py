"""``gsjax tune``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "tune",
        help="tune traced config fields on a recording by their hypergradients (gradient descent on SLAM itself)",
        description="Gradient-based search over traced config fields: each step runs SLAM on the recording's frames "
        "(--max-frames of them), differentiates the objective with respect to --params through the tracker "
        "(each frame's map held fixed) and takes an Adam step (a learning rate on a log scale, other fields relative "
        "to their start, within their bounds). --objective residual needs no ground truth (each frame rendered at "
        "its tracked pose from the map built before it: depth L1 + colour L1); ate needs it. Start values: "
        "--FIELD VALUE (e.g. --tracking.lr_trans 2e-4); other dotted overrides set the config. Writes tuned.json "
        "(apply it with gsjax run --tuned FILE), tune.csv and tune.png.",
        parents=[common.COMMON],
    )
    common.add_sequence_flags(p)
    p.add_argument("--params", required=True, metavar="F1,F2,...",
                   help="comma-separated dotted names of traced float fields to tune, e.g. "
                        "tracking.lr_trans,tracking.lr_rot")
    p.add_argument("--objective", choices=("residual", "ate"), default="residual",
                   help="what to minimise: residual (no ground truth needed; default) or ate (needs it)")
    p.add_argument("--steps", type=common.positive, default=10, help="Adam steps (default 10: 11 SLAM runs)")
    p.add_argument("--step-size", type=float, default=0.25,
                   help="Adam's step in the search space (default 0.25: a quarter of an e-fold of a learning rate, a "
                        "quarter of another field's start); halved after a step that raises the objective")
    p.add_argument("--overwrite", action="store_true", help="replace a previous tuning in --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run, accepts_overrides=True)


def run(args) -> int:
    from gsjax.app.run_folder.layout import check_run_dir
    from gsjax.app.tune import TuneOptions, run_tune, tuning_start
    from gsjax.io.run_folder import TUNE_FILES

    common.quiet_logs()
    fields = tuple(name.strip() for name in args.params.split(",") if name.strip())
    starts = {name: args.overrides.pop(name) for name in fields if name in args.overrides}
    try:
        start_values = {name: float(text) for name, text in starts.items()}
    except ValueError:
        raise common.UserError(f"a start value must be a number: {starts}") from None
    if not args.step_size > 0:
        raise common.UserError(f"--step-size must be > 0, got {args.step_size}")
    tuning_start(common.configure(args), fields, start_values)  # bad fields are reported before any data is read
    check_run_dir(args.out, overwrite=args.overwrite, outputs=TUNE_FILES)
    (sequence, factor), _ = common.dataset_warnings(lambda: common.open_run_sequence(args))
    describe = common.describe_run(args, sequence, factor)
    config = common.configure(args, sequence.intrinsics.width)
    options = TuneOptions(out=args.out, fields=fields, starts=start_values, objective=args.objective,
                          steps=args.steps, step_size=args.step_size, seed=args.seed, overwrite=args.overwrite,
                          progress=not args.no_progress)
    print(f"gsjax tune: {sequence!r}, preset {args.preset}, CB-KNN {args.cbknn}, downscale {factor}: "
          f"{', '.join(fields)} by the {args.objective} objective, {args.steps} steps -> {args.out}", flush=True)
    document = run_tune(sequence, config, options, describe=describe)
    start = ", ".join(f"{name} {value:.4g}" for name, value in document["start"].items())
    tuned = ", ".join(f"{name} {value:.4g}" for name, value in document["fields"].items())
    print(f"{args.objective}: {document['start_value']:.5g} at the start ({start}); lowest {document['value']:.5g} "
          f"at step {document['step']} ({tuned}); {document['seconds']:.0f} s")
    print(f"outputs in {args.out.resolve()}: tuned.json tune.csv tune.png (gsjax run --tuned "
          f"{args.out / 'tuned.json'})")
    return 0
