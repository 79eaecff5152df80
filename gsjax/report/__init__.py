"""``report.html``: the self-contained HTML report of a run, or of several runs side by side (``gsjax report``).

* :mod:`gsjax.io.run_folder`: a finished run read back from its directory (also used by the viewer).
* :mod:`gsjax.report.figures`: the plots, as SVG (the page) or PNG (a file) bytes.
* :mod:`gsjax.report.page`: the page.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from gsjax.eval.run_metrics import RunMetrics
from gsjax.io.atomic import atomic_write_text
from gsjax.io.run_folder import RunRecord, RunRecordError, expand_runs, read_run
from gsjax.report.page import is_report, report_html

__all__ = ["RunRecord", "RunRecordError", "default_output", "expand_runs", "read_run", "report_html",
           "write_report"]


def default_output(paths: list[Path]) -> Path:
    """Where ``gsjax report PATHS`` writes without ``--out``: a run's (or a sweep's) own ``report.html``;
    ``report.html`` in the current directory for several runs."""
    if len(paths) == 1:
        return Path(paths[0]) / "report.html"
    return Path("report.html")


def write_report(paths: str | Path | list[str | Path], out: str | Path | None = None,
                 metrics: RunMetrics | None = None) -> Path:
    """Write the report of the run(s) in ``paths`` to ``out`` (default :func:`default_output`), atomically.

    ``paths``: a run directory, a sweep directory (its ``runs/*`` side by side) or a list of them; ``metrics``
    stands in for a single run's ``metrics.json`` while the run writes its outputs. An existing ``out`` is replaced
    only if it is a gsjax report. Raises :class:`RunRecordError` naming what cannot be read.
    """
    paths = [Path(paths)] if isinstance(paths, (str, Path)) else [Path(p) for p in paths]
    out = Path(out) if out is not None else default_output(paths)
    if out.is_dir():
        raise RunRecordError(f"--out {out} is a directory; give the report's file name (e.g. {out / 'report.html'})")
    if out.exists() and not is_report(out):
        raise RunRecordError(f"{out} exists and is not a gsjax report; nothing was changed: choose another --out")
    runs = expand_runs(paths)
    if metrics is not None and len(runs) != 1:
        raise ValueError("metrics= stands in for one run's metrics.json; give one run directory")
    records = [read_run(path, metrics) for path in runs]
    if not records:
        raise RunRecordError(f"{', '.join(map(str, paths))}: no runs to report")
    return atomic_write_text(out, report_html(_distinct_names(records)))


def _distinct_names(runs: list[RunRecord]) -> list[RunRecord]:
    """The runs, each named by the shortest tail of its path that tells it from the others (``runs/003``,
    ``off/run``), so table rows and legends are unambiguous."""
    parts = [run.path.resolve().parts for run in runs]
    for depth in range(1, max(len(p) for p in parts) + 1):
        names = ["/".join(p[-depth:]) for p in parts]
        if len(set(names)) == len(names):
            break
    return [dataclasses.replace(run, name=name) for run, name in zip(runs, names)]
