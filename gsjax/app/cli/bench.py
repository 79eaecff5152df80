"""``gsjax bench``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from pathlib import Path

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "bench", help="rasterizer and tracking-iteration speed and memory per backend on this device",
        description="Time the render forward, forward+backward and one tracking iteration (median after a warm-up, "
        "compile time apart), ns per pixel x candidate and the peak memory of a tracking iteration, for each "
        "backend and image size, on a SplaTAM-density map of a synthetic room. Prints a table and writes JSON. "
        "On a CPU the pallas backend runs in interpret mode (slow: a correctness aid, not a speed).",
        parents=[common.COMMON])
    p.add_argument("--backend", type=common.backends, default=None, metavar="LIST",
                   help="comma-separated backends: xla, pallas (default: xla,pallas on a GPU, xla elsewhere)")
    p.add_argument("--sizes", type=common.sizes, default=[(640, 480), (1200, 680)], metavar="WxH,...",
                   help="image sizes (default 640x480,1200x680)")
    p.add_argument("--gaussians", type=common.positive, default=None, metavar="N",
                   help="active Gaussians in the map (default: about one per pixel, SplaTAM's density)")
    p.add_argument("--k", type=common.positive, default=96, help="contributor slots per pixel (default 96, SLAM's)")
    p.add_argument("--repeats", type=common.positive, default=5, help="timed runs after the warm-up (default 5)")
    p.add_argument("--out", type=Path, default=Path("bench.json"), help="the JSON to write (default bench.json)")
    p.set_defaults(func=run)


def run(args) -> int:
    from gsjax.app.bench import run_bench
    from gsjax.io.atomic import atomic_write_json
    from gsjax.raster import pallas

    if args.out.is_dir():
        raise common.UserError(f"--out {args.out} is a directory; give the JSON file to write")
    backends = args.backend or (["xla", "pallas"] if pallas.on_gpu() else ["xla"])
    result = run_bench(backends, args.sizes, args.gaussians, args.repeats, args.k,
                       log=lambda line: print(line, flush=True))
    print(f"wrote {atomic_write_json(args.out, result)}")
    return 0
