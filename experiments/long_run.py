"""A long run of the synthetic scene: memory, time per frame, Gaussian count and checkpoint cost every 100 frames.

    python experiments/long_run.py --frames 1000 --work /tmp/gsjax_long [--downscale 4]

Runs ``gsjax run --dataset synthetic --max-frames N --downscale F`` in process (the ``cpu`` preset, default
``--checkpoint-every 8``) and records after each chunk: the process's resident memory (VmRSS) and peak (VmHWM)
from ``/proc/self/status``, the wall time of the frames since the last mark, active Gaussians and capacity, each
checkpoint's seconds and bytes written, and the checkpoint directory's size. Writes
``experiments/results/long_run.json``. The measurement is :func:`gsjax.app.long_run.long_run`, which
``tests/app/test_slow_long_run.py`` asserts on.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gsjax.app.long_run import long_run

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--downscale", type=int, default=4)
    parser.add_argument("--checkpoint-every", type=int, default=8)
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="a config override")
    parser.add_argument("--result", type=Path, default=RESULTS / "long_run.json")
    parser.add_argument("--work", type=Path, required=True)
    args = parser.parse_args(argv)
    overrides = dict(item.split("=", 1) for item in args.set)
    result = long_run(args.frames, args.work, args.downscale, checkpoint_every=args.checkpoint_every,
                      overrides=overrides)
    result["command"] = " ".join(["python", "experiments/long_run.py", *(argv or sys.argv[1:])])
    path = args.result
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
