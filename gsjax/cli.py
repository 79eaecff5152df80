"""The ``gsjax`` command line: the imperative shell around the pure core.

Each subcommand has an ``_add_<name>(subparsers)`` that declares its flags and a ``_cmd_<name>(args)`` that runs
it. Heavy imports happen inside the command functions so ``gsjax --help`` stays fast. User errors (bad paths,
bad values) are reported as one line ``gsjax <cmd>: error: ...`` with exit status 2, never a stack trace.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


class UserError(Exception):
    """An error caused by the user's input; printed without a traceback."""


def _add_demo(sub) -> None:
    p = sub.add_parser("demo", help="render the built-in synthetic scene and write the images")
    p.add_argument("--out", type=Path, default=Path("outputs/demo"), help="output directory")
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args) -> int:
    from gsjax.demo import run_demo

    for line in run_demo(args.out):
        print(line)
    return 0


def _add_synth(sub) -> None:
    p = sub.add_parser("synth", help="render a synthetic RGB-D sequence and write it in the TUM RGB-D layout")
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gsjax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (_add_demo, _add_synth):
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from gsjax.compilation_cache import enable_compilation_cache

    enable_compilation_cache()
    try:
        return int(args.func(args) or 0)
    except (UserError, ValueError, FileNotFoundError) as err:
        print(f"gsjax {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
