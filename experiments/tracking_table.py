"""The README's tracking table from fresh runs, and the ATE bounds the slow suite holds them to.

    python experiments/tracking_table.py --work /tmp/gsjax_tracking [--rows synthetic,7scenes_40] [--update-readme]

Each row is ``gsjax run --preset cpu`` on one sequence, CB-KNN off and paper. Runs go to ``--work DIR/ROW_MODE``
(outside git). A run already finished there with the same options is reused: ``--resume`` on a finished run only
re-evaluates it (and refuses other options), so ``make test-slow`` with ``GSJAX_SLOW_WORK=DIR`` followed by this
script with ``--work DIR`` measures each run once. Writes ``experiments/results/tracking_table.md`` and ``.json``;
``--update-readme`` replaces the table under "## Measured tracking" in README.md.

The rows, their ATE bounds and the run of one row are :mod:`gsjax.app.tracking_table` (shared with the slow suite).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from gsjax.app.tracking_table import BOUNDS_CM, MODES, ROWS, available, run_row, seed_bound, shared_data, summary

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
def markdown(results: dict) -> str:
    lines = ["| sequence | frames | ATE RMSE off / paper | constant pose | PSNR off / paper | s/frame off / paper |",
             "|---|---|---|---|---|---|"]
    for row in ROWS:
        if row.name not in results:
            continue
        off, paper = results[row.name]["off"], results[row.name]["paper"]
        seconds = (f"{off['s_per_frame']:.1f} / {paper['s_per_frame']:.1f}" if row.frames >= 30
                   else "(compile-dominated)")
        lines.append(f"| {row.label} | {row.frames} | {off['ate_cm']:.2f} / {paper['ate_cm']:.2f} cm | "
                     f"{off['constant_cm']:.2f} cm | {off['psnr_db']:.1f} / {paper['psnr_db']:.1f} dB | {seconds} |")
    return "\n".join(lines) + "\n"


def update_readme(table: str, readme: Path = ROOT / "README.md") -> None:
    text = readme.read_text()
    pattern = re.compile(r"(## Measured tracking[^\n]*\n\n)(\|.*?\n)(?=\n)", re.S)
    if not pattern.search(text):
        raise SystemExit(f"{readme}: no table under '## Measured tracking'")
    readme.write_text(pattern.sub(lambda m: m.group(1) + table, text, count=1))
    print(f"updated {readme}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="run directories (outside git; reused)")
    parser.add_argument("--rows", default=",".join(r.name for r in ROWS), help="comma-separated row names")
    parser.add_argument("--update-readme", action="store_true")
    parser.add_argument("--seed-bound", metavar="ROW", default=None,
                        help="instead: ROW's ATE over 5 seeds per mode and its bound mean + 3 std (the Replica "
                             "sample's bound, recomputed whenever the cpu preset changes)")
    args = parser.parse_args(argv)
    if args.seed_bound:
        row = next(r for r in ROWS if r.name == args.seed_bound)
        bounds = {mode: seed_bound(row, mode, args.work) for mode in MODES}
        for mode, b in bounds.items():
            print(f"{row.name} {mode}: ATE {', '.join(f'{v:.3f}' for v in b['ate_cm'])} cm; mean {b['mean_cm']:.3f}, "
                  f"std {b['std_cm']:.3f}, bound {b['bound_cm']:.2f} cm (now {BOUNDS_CM[(row.name, mode)]:.2f})")
        (RESULTS / f"seed_bound_{row.name}.json").write_text(json.dumps(bounds, indent=2) + "\n")
        return 0
    wanted = args.rows.split(",")
    unknown = set(wanted) - {r.name for r in ROWS}
    if unknown:
        parser.error(f"unknown rows {sorted(unknown)}; known: {[r.name for r in ROWS]}")
    results = {}
    for row in ROWS:
        if row.name not in wanted:
            continue
        if not available(row):
            print(f"skipping {row.name}: {shared_data() / row.needs} is absent", file=sys.stderr)
            continue
        results[row.name] = {mode: summary(run_row(row, mode, args.work)) for mode in MODES}
        for mode in MODES:
            ate, bound = results[row.name][mode]["ate_cm"], BOUNDS_CM[(row.name, mode)]
            print(f"{row.name} {mode}: ATE {ate:.3f} cm (bound {bound:.2f})", flush=True)
    table = markdown(results)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "tracking_table.md").write_text(table)
    (RESULTS / "tracking_table.json").write_text(json.dumps(results, indent=2) + "\n")
    print(table)
    if args.update_readme:
        update_readme(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
