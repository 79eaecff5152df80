"""The ``gsjax`` command line: the imperative shell around the pure core.

Each subcommand is a module of this package with ``add(subparsers)``, which declares its flags, and
``run(args)``, which runs it. Heavy imports happen inside ``run`` so ``gsjax --help`` stays fast. User errors (bad
paths, bad values, bad data) are reported as one line ``gsjax <cmd>: error: ...`` with exit status 2, never a stack
trace (``--debug`` shows it); what gsjax handles in a defined way is printed as ``warning: ...``.
:mod:`~gsjax.app.cli.common` holds what the commands share (argument types, the common flags, opening a run's
sequence).
"""

from __future__ import annotations

import argparse
import sys
import warnings

from gsjax.app.cli import (
    bench,
    config,
    evaluate,
    landscape,
    report,
    run,
    sweep,
    synth,
    tune,
    view,
)
from gsjax.app.cli.common import Parser, UserError, parse_overrides, show_warning

COMMANDS = (run, sweep, tune, landscape, report, view, bench, evaluate, synth, config)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="gsjax", description="Dense RGB-D SLAM with 3D Gaussian Splatting and CB-KNN, in JAX.")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:  # a usage error (or --help) exits from argparse; in-process callers get its status back
        args, extra = parser.parse_known_args(argv)
        if extra and not getattr(args, "accepts_overrides", False):
            parser.error(f"unrecognised arguments: {' '.join(extra)}")
    except SystemExit as exit_:
        return int(exit_.code or 0)
    from gsjax.app.runtime.cache import enable_compilation_cache
    from gsjax.app.runtime.memory import limit_malloc_arenas

    enable_compilation_cache()
    limit_malloc_arenas()
    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            args.overrides = parse_overrides(extra)
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
