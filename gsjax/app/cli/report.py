"""``gsjax report``: its flags (:func:`add`) and its body (:func:`run`)."""

from __future__ import annotations

from pathlib import Path

from gsjax.app.cli import common


def add(sub) -> None:
    p = sub.add_parser(
        "report", help="the self-contained HTML report of a run, or of several runs side by side",
        description="Write report.html: metrics, the trajectory against ground truth, ATE and RPE over time, renders "
        "against inputs with error maps, PSNR per frame, Gaussian count, timings, CB-KNN's K and rho maps, warnings "
        "and the config. One RUN: RUN/report.html (gsjax run writes it too). A sweep's directory: its runs side by "
        "side in SWEEP/report.html. Several RUNs: side by side in ./report.html.",
        parents=[common.COMMON])
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN", help="a gsjax run's (or sweep's) output directory")
    p.add_argument("--out", type=Path, default=None,
                   help="the page to write (default: see above; an existing file is replaced only if it is a gsjax "
                        "report)")
    p.set_defaults(func=run)


def run(args) -> int:
    from gsjax.report import write_report

    path = write_report(args.runs, args.out)
    print(f"wrote {path}")
    return 0
