"""``gsjax synth``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from pathlib import Path

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser("synth", help="render a synthetic RGB-D sequence and write it in the TUM RGB-D layout",
                       parents=[common.COMMON])
    p.add_argument("--out", type=Path, required=True, help="output directory (must not exist or be empty)")
    p.add_argument("--frames", type=int, default=60, help="number of frames (default 60)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--noise", action="store_true", help="add Kinect-like sensor noise, holes and blur")
    p.set_defaults(func=run)


def run(args) -> int:
    from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
    from gsjax.data.tum import write_tum

    if args.frames < 1:
        raise common.UserError(f"--frames must be >= 1, got {args.frames}")
    if args.out.exists() and (not args.out.is_dir() or any(args.out.iterdir())):
        raise common.UserError(f"--out {args.out} already exists and is not an empty directory; refusing to overwrite")
    config = SyntheticConfig(num_frames=args.frames, seed=args.seed)
    if args.noise:
        config = config.with_sensor_noise()
    write_tum(synthetic_sequence(config), args.out)
    print(f"wrote {args.frames} frames ({config.width}x{config.height}) in the TUM layout to {args.out}")
    return 0
