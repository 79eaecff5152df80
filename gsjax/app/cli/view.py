"""``gsjax view``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from pathlib import Path

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "view", help="a browser viewer of a run: the map as splats, trajectories, keyframes, a frame slider",
        description="Serve the finished run in RUN_DIR to a browser (viser): the Gaussian map as splats, the "
        "estimated and ground-truth trajectories with keyframe frustums, the input and rendered images of the "
        "selected keyframe and a frame slider. Stops on Ctrl-C (SIGINT) or SIGTERM.",
        parents=[common.COMMON])
    p.add_argument("run", type=Path, metavar="RUN_DIR", help="a gsjax run's output directory")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=common.port, default=8080,
                   help="port (default 8080; the next free one if taken; 0: any free port)")
    p.set_defaults(func=run)


def run(args) -> int:
    from gsjax.viewer import open_run, wait_for_stop

    common.quiet_logs()
    viewer = open_run(args.run, host=args.host, port=args.port)
    try:
        print(f"viewer: {viewer.url} shows {args.run}; Ctrl-C or SIGTERM stops it", flush=True)
        print(f"viewer stopped ({wait_for_stop()})", flush=True)
    finally:
        viewer.stop()
    return 0
