"""Shared parts of the CB-KNN studies (robustness, ablation, alpha x K0 x beta): the sequences, running `gsjax sweep`
as a user would, and writing a result CSV whose header holds the exact commands.

Each study runs its sweeps into ``--work DIR`` (outside git; a sweep already finished there is reused, so an
interrupted study continues), keeps each finished sweep's rows (a few KB) under ``experiments/results/runs/``, where
they are reused when ``--work`` no longer holds that sweep (a later session, another machine), and writes a small CSV
and a figure under ``experiments/results/``.
"""

from __future__ import annotations

import csv
import io
import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
RUNS = RESULTS / "runs"
# resolved, so that a checkout whose ../shared is a link runs (and keeps) the same commands
SEVEN_SCENES = (ROOT.parent / "shared" / "data" / "7scenes_redkitchen").resolve()
REPLICA = (ROOT.parent / "shared" / "data" / "replica_office0_mini" / "office0").resolve()

# name -> the gsjax flags that select it, at the cpu preset's own working size (about 80 px wide: the synthetic
# 160x120 at downscale 2, 7-Scenes' 640x480 at 8, Replica's 1200x680 at 15, 80x45).
SEQUENCES = {
    "synthetic_noisy": ["--dataset", "synthetic", "--synthetic-noise"],
    "7scenes": ["--dataset", "7scenes", "--path", str(SEVEN_SCENES)],
    "replica": ["--dataset", "replica", "--path", str(REPLICA)],
}
# The studies before 2026-12-04 ran at 40x30 (these flags); their CSVs' headers hold the exact commands.
SEQUENCES_40 = {
    "synthetic_noisy": ["--dataset", "synthetic", "--synthetic-noise", "--downscale", "4"],
    "7scenes": ["--dataset", "7scenes", "--path", str(SEVEN_SCENES), "--downscale", "16"],
}
# Frames each sequence has (the Replica sample holds 4).
AVAILABLE_FRAMES = {"synthetic_noisy": None, "7scenes": 150, "replica": 4}


def sweep(work: Path, name: str, argv: list[str], log: list[str], keep: str | None = None) -> list[dict]:
    """Run ``gsjax sweep --out work/name argv`` unless it already finished there; its rows (strings). Appends the
    command and the sweep's wall time to ``log``.

    With ``keep`` (the study's name), the finished sweep's rows are also kept as ``RUNS/keep/name.csv`` under its
    command, and taken from there when ``work/name`` holds no finished sweep but the kept command is the same."""
    out = work / name
    command = [sys.executable, "-m", "gsjax", "sweep", "--out", str(out), "--no-progress", *argv]
    kept = RUNS / keep / f"{name}.csv" if keep else None
    if not (out / "sweep.csv").is_file():
        found = _kept(kept, argv)
        if found is not None:
            wall, rows = found
            log.append(_logged(command, wall, kept))
            return rows
        if out.exists():
            command.append("--overwrite")  # an interrupted sweep: its partial outputs are replaced
        print("running: gsjax", shlex.join(command[3:]), flush=True)
        subprocess.run(command, check=True, cwd=ROOT)
    wall = json.loads((out / "sweep.json").read_text()).get("wall_s")
    wall = "?" if wall is None else f"{wall:.0f}"
    text = (out / "sweep.csv").read_text()
    if kept is not None:
        kept.parent.mkdir(parents=True, exist_ok=True)
        kept.write_text(f"# argv: {shlex.join(argv)}\n# wall_s: {wall}\n{text}")
    log.append(_logged(command, wall, kept))
    return list(csv.DictReader(io.StringIO(text)))


def _logged(command: list[str], wall: str, kept: Path | None) -> str:
    """A sweep's line in a result's header: its command, wall time and where its rows are kept."""
    where = f"; rows kept in {kept.relative_to(ROOT).as_posix()}" if kept is not None else ""
    return f"gsjax {shlex.join(command[3:])}  (wall {wall} s{where})"


def _kept(kept: Path | None, argv: list[str]) -> tuple[str, list[dict]] | None:
    """(wall time, rows) of a kept sweep run with ``argv``; None when there is none."""
    if kept is None or not kept.is_file():
        return None
    argv_line, wall_line, body = kept.read_text().split("\n", 2)
    if argv_line != f"# argv: {shlex.join(argv)}":
        return None  # kept from another command: run it again
    return wall_line.removeprefix("# wall_s: "), list(csv.DictReader(io.StringIO(body)))


EARLIER = "earlier, rows not kept: "
EARLIER_KEPT = "earlier: "  # a sweep of an earlier run whose rows are kept in RUNS


def carried_over(path: Path, keys: list[str], fresh: list[dict], sweep_of) -> tuple[list[str], list[dict]]:
    """What to keep of the result CSV ``path`` from an earlier run of the study whose sweeps are neither in ``--work``
    nor kept (results older than ``RUNS``): its rows whose ``keys`` no row of ``fresh`` has, and the commands (to
    log) of the sweeps they came from, ``sweep_of(row)`` naming a row's sweep."""
    if not path.is_file():
        return [], []
    lines = path.read_text().splitlines()
    done = {tuple(str(r[k]) for k in keys) for r in fresh}
    rows = [r for r in csv.DictReader(line for line in lines if not line.startswith("#"))
            if tuple(r[k] for k in keys) not in done]
    names = {sweep_of(r) for r in rows}
    commands = [line.removeprefix("# ran: ").removeprefix(EARLIER).removeprefix(EARLIER_KEPT)
                for line in lines if line.startswith("# ran: ")]
    return [(EARLIER_KEPT if "rows kept in " in c else EARLIER) + c
            for c in commands if any(f"/{n} " in c or f" {n} " in c for n in names)], rows


def write_result_csv(path: Path, rows: list[dict], columns: list[str], commands: list[str]) -> Path:
    """``rows`` as CSV under ``# command:`` header lines (the study's own command line first)."""
    buffer = io.StringIO()
    script = Path(sys.argv[0]).resolve()
    script = script.relative_to(ROOT) if script.is_relative_to(ROOT) else script
    buffer.write(f"# command: {shlex.join(['python', script.as_posix(), *sys.argv[1:]])}\n")
    for command in commands:
        buffer.write(f"# ran: {command}\n")
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(buffer.getvalue())
    print(f"wrote {path}")
    return path


def mean_std(values) -> tuple[float, float, int]:
    """(mean, sample std, count) of the finite values."""
    v = np.asarray([float(x) for x in values if x not in ("", None)], np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan"), 0
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0, int(v.size)


def paired_rows(rows: list[dict], keys: list[str], metric: str = "ate_rmse_cm", a: str = "off",
                b: str = "paper", label: str = "cbknn.mode", pair: str = "seed") -> list[dict]:
    """Per group of ``keys``: the paired difference b - a (``difference``; ``a_mean``, ``b_mean`` the two means over
    the shared pairs) of ``metric`` between the rows whose ``label`` column is ``b`` and ``a``, paired by the
    ``pair`` column (the seed; a landscape's frame), over the pairs both have
    (:func:`gsjax.eval.stats.paired_difference`, 95 % bootstrap interval and Student's t interval), with n."""
    from gsjax.eval.stats import paired_difference

    groups: dict = {}
    for row in rows:
        key = tuple(row[k] for k in keys)
        value = float(row[metric]) if row[metric] not in ("", None) else float("nan")
        groups.setdefault(key, {}).setdefault(row[label], {})[str(row[pair])] = value
    out = []
    for key, modes in groups.items():
        if a not in modes or b not in modes:
            continue
        seeds = sorted(set(modes[a]) & set(modes[b]), key=int)
        found = paired_difference([modes[a][s] for s in seeds], [modes[b][s] for s in seeds])
        out.append({**dict(zip(keys, key)), "metric": metric, "n": found.n, "a": a, "a_mean": _mean(modes[a], seeds),
                    "b": b, "b_mean": _mean(modes[b], seeds), "difference": found.mean, "ci_low": found.low,
                    "ci_high": found.high, "t_low": found.t_low, "t_high": found.t_high,
                    "excludes_zero": found.excludes_zero})
    return out


def _mean(values: dict, seeds: list) -> float:
    finite = [values[s] for s in seeds if np.isfinite(values[s])]
    return float(np.mean(finite)) if finite else float("nan")


def summarise(rows: list[dict], keys: list[str], metric: str = "ate_rmse_cm") -> list[dict]:
    """Rows grouped by ``keys`` with the metric's mean, std and count over the group (the seeds)."""
    groups: dict = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in keys), []).append(row[metric])
    out = []
    for key, values in groups.items():
        mean, std, n = mean_std(values)
        out.append({**dict(zip(keys, key)), f"{metric}_mean": mean, f"{metric}_std": std, "seeds": n})
    return out
