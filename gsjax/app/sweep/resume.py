"""``gsjax sweep --resume``: which configs a killed sweep finished, so only the others run again.

A config is finished when its ``runs/NNN/metrics.json`` exists: a run writes it last, atomically, so its presence
means every other output of the run is whole. A folder without it (a sweep killed inside that config, or while
writing its outputs) is run again; its files are replaced and what a killed writer left (hidden temporaries) is
removed. A finished run made with another config, or outside the grid, stops the resume before anything changes.
"""

from __future__ import annotations

from pathlib import Path

from gsjax.app.run_folder.layout import RunDirError
from gsjax.config.text import canonical_config_dict
from gsjax.eval.run_input import RUN_FORMAT, RunInput, older_run_message
from gsjax.eval.run_metrics import RunMetrics
from gsjax.io.atomic import remove_stale_temporaries
from gsjax.io.run_folder import RENDERS, is_finished, read_config, read_metrics, sweep_run


def finished_runs(out: Path, expected: dict[int, RunInput]) -> dict[int, RunMetrics]:
    """The configs of the sweep in ``out`` a previous sweep finished, by index, with their metrics.

    ``expected``: each config's ``config.json`` record as this sweep makes it; a finished run must match its size,
    chunk, seed, camera, config (:meth:`RunInput.resume_key`) and grid values. Raises RunDirError naming the run
    otherwise, having changed nothing.
    """
    runs = Path(out) / "runs"
    done: dict[int, RunMetrics] = {}
    if not runs.is_dir():
        return done
    for folder in sorted(p for p in runs.iterdir() if p.is_dir()):
        if not is_finished(folder):
            continue
        index = int(folder.name) if folder.name.isdigit() else -1
        if index not in expected:
            raise RunDirError(f"--resume: {folder} is a finished run outside this sweep's {len(expected)} configs; "
                              "resume with the same --grid and --seeds, or use --overwrite or a new --out")
        try:
            saved, metrics = read_config(folder), read_metrics(folder)
        except ValueError as error:
            raise RunDirError(f"--resume: {error}") from None
        if saved.format != RUN_FORMAT:
            raise RunDirError(f"--resume: {older_run_message(folder, saved.format)}")
        want = expected[index]
        if _comparable(saved) != _comparable(want):
            raise RunDirError(f"--resume: {folder} was made with a different config, size, chunk or seed than this "
                              "sweep's; resume with the same options, or use --overwrite or a new --out")
        done[index] = metrics
    return done


def _comparable(record: RunInput) -> tuple[dict, dict]:
    """What a finished run must match, as this version writes it."""
    key = dict(record.resume_key(), config=canonical_config_dict(record.config))
    return key, (record.sweep or {}).get("values") or {}


def prepare_rerun(out: Path, index: int) -> None:
    """Remove what a killed writer left in config ``index``'s folder (hidden temporaries; never a whole output)."""
    folder = sweep_run(out, index)
    for directory in (folder, folder / RENDERS):
        if directory.is_dir():
            remove_stale_temporaries(directory)
