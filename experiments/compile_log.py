"""The suite's compilations as a table: distinct programs by kind, and where the compile time goes.

``GSJAX_COMPILE_LOG=DIR`` makes every process of a test run (the pytest workers and the ``gsjax`` commands they
start) append a line per compiled program to ``DIR/<pid>.tsv`` (:mod:`gsjax.app.runtime.compile_log`): the test or
command, the program's name, its trace, lowering and XLA compile seconds, and whether XLA's part was a persistent-cache
hit. 
    GSJAX_CACHE_DIR=$(mktemp -d) GSJAX_COMPILE_LOG=/tmp/clog make test
    python experiments/compile_log.py /tmp/clog [--top 20] [--tests-only]

A compilation that is not a cache hit is a distinct program (the two pytest workers share the cache and take a
lock per SLAM program, so what one compiled the other loads). Kinds, by the jitted function's name: the SLAM scan
(``run_chunk``, exported as ``call``), a tracker (``track``), mapping (``map_window``), the landscape, renders
(``_render``, ``render``, ``_select``), and small eager ops (``jit(add)``, ...: one primitive each).
"""

from __future__ import annotations

import argparse
import collections
import re
from pathlib import Path

KINDS = (  # (kind, pattern on the program's name), first match wins
    ("SLAM scan (run_chunk)", r"run_chunk|^jit\(call\)$|run_batch_chunk"),
    ("tracker", r"track"),
    ("mapping", r"map_window|_map"),
    ("landscape", r"landscape|loss_and_grad|_evaluate"),
    ("render", r"_render|^jit\(render\)|_select|select_slots"),
    ("loss / gradient", r"loss|grad"),
)
SMALL_S = 0.5  # a compilation under this (trace + lower + compile) counts as a small op


def read(directory: Path) -> list[dict]:
    rows = []
    for path in sorted(Path(directory).glob("*.tsv")):
        for line in path.read_text().splitlines():
            test, program, trace, lower, compile_, hit = line.split("\t")
            rows.append(dict(test=test, program=program, trace=float(trace), lower=float(lower),
                             compile=float(compile_), hit=hit == "1", pid=path.stem))
    return rows


def kind_of(row: dict) -> str:
    for kind, pattern in KINDS:
        if re.search(pattern, row["program"]):
            return kind
    total = row["trace"] + row["lower"] + row["compile"]
    return "small op (< 0.5 s)" if total < SMALL_S else "other"


def table(rows: list[dict]) -> list[tuple]:
    """(kind, programs compiled, cache hits, trace s, lower s, compile s) per kind, the most compile time first."""
    by = collections.defaultdict(lambda: [0, 0, 0.0, 0.0, 0.0])
    for row in rows:
        entry = by[kind_of(row)]
        entry[1 if row["hit"] else 0] += 1
        entry[2] += row["trace"]
        entry[3] += row["lower"]
        entry[4] += 0.0 if row["hit"] else row["compile"]
    return sorted(((k, *v) for k, v in by.items()), key=lambda r: -(r[3] + r[4] + r[5]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("directory", type=Path)
    parser.add_argument("--top", type=int, default=15, help="also list the tests with the most compile time")
    parser.add_argument("--tests-only", action="store_true",
                        help="leave out the gsjax commands the tests start (their own processes), to compare with a "
                             "log of the pytest workers alone")
    args = parser.parse_args()
    rows = read(args.directory)
    if args.tests_only:
        rows = [row for row in rows if not row["test"].startswith("gsjax ")]
    print("| kind | programs compiled | cache hits | trace s | lower s | XLA compile s |")
    print("|---|---|---|---|---|---|")
    totals = [0, 0, 0.0, 0.0, 0.0]
    for kind, *values in table(rows):
        totals = [a + b for a, b in zip(totals, values)]
        print(f"| {kind} | {values[0]} | {values[1]} | {values[2]:.0f} | {values[3]:.0f} | {values[4]:.0f} |")
    print(f"| all | {totals[0]} | {totals[1]} | {totals[2]:.0f} | {totals[3]:.0f} | {totals[4]:.0f} |")
    per_test = collections.Counter()
    for row in rows:
        per_test[row["test"]] += row["trace"] + row["lower"] + (0.0 if row["hit"] else row["compile"])
    print(f"\nThe {args.top} tests with the most tracing + compiling (s):")
    for test, seconds in per_test.most_common(args.top):
        print(f"  {seconds:6.1f}  {test}")


if __name__ == "__main__":
    main()
