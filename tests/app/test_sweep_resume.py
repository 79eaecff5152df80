"""``gsjax sweep --resume``: a sweep killed anywhere (inside the scan, between one config's outputs and the next's,
mid-write of ``sweep.csv``) and resumed leaves the configs it had finished untouched, runs the others again, and
ends with the rows and runs of an uninterrupted sweep; a resume with another grid is refused."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from gsjax.app.cli import main
from gsjax.app.sweep.grid import read_sweep_csv
from tests.support.kill_harness import KILL_EXIT
from tests.support.tiny_slam import TINY_RUN

HARNESS = Path(__file__).parents[1] / "support" / "kill_harness.py"
SWEEP = ["sweep", *TINY_RUN, "--grid", "tracking.lr_trans=0.002,0.004"]


def harness(out: Path, trace: Path, kill_at: str, resume: bool) -> subprocess.CompletedProcess:
    argv = [*SWEEP, "--out", str(out)] + (["--resume"] if resume else [])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HARNESS.parent), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, str(HARNESS), str(trace), kill_at, "--", *argv], env=env,
                          capture_output=True, text=True, timeout=600)


def files(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``folder`` but the folder's lock (which a sweep takes before it checks anything): its bytes
    and modification time (ns)."""
    return {str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".gsjax.lock"}


def rows(out: Path) -> list[dict]:
    return [{k: v for k, v in row.items() if k != "seconds"} for row in read_sweep_csv(out / "sweep.csv")]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole") / "sweep"
    assert main([*SWEEP, "--out", str(out)]) == 0
    return out


def test_killed_anywhere_and_resumed_the_sweep_equals_an_uninterrupted_one(tmp_path, uninterrupted):
    out, trace = tmp_path / "sweep", tmp_path / "trace"
    killed = harness(out, trace, "scan:3", resume=False)  # both configs' second chunk: nothing finished
    assert killed.returncode == KILL_EXIT, killed.stderr
    assert not (out / "runs").exists()
    killed = harness(out, trace, "write:001/config.json", resume=True)  # config 0 finished, config 1 not begun
    assert killed.returncode == KILL_EXIT, killed.stderr
    assert (out / "runs" / "000" / "metrics.json").exists() and not (out / "runs" / "001" / "config.json").exists()
    first = files(out / "runs" / "000")
    killed = harness(out, trace, "write:sweep/sweep.csv", resume=True)  # every config finished, the table half written
    assert killed.returncode == KILL_EXIT, killed.stderr
    assert "1 of 2 configs finished before" in killed.stdout
    assert not (out / "sweep.csv").exists()
    done = harness(out, trace, "-", resume=True)
    assert done.returncode == 0, done.stderr
    assert "2 of 2 configs finished before; running the other 0" in done.stdout
    assert files(out / "runs" / "000") == first  # untouched, to the nanosecond
    assert rows(out) == rows(uninterrupted)
    for run in ("000", "001"):
        for name in ("trajectory.txt", "map.ply"):
            assert (out / "runs" / run / name).read_bytes() == (uninterrupted / "runs" / run / name).read_bytes()
    assert not [p for p in out.rglob(".*.tmp")]


def test_a_resume_with_another_grid_is_refused_naming_the_run(tmp_path, uninterrupted, capsys):
    import shutil

    out = tmp_path / "sweep"
    shutil.copytree(uninterrupted, out)
    before = files(out)
    assert main(["sweep", *TINY_RUN, "--grid", "tracking.lr_trans=0.002,0.003", "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "--resume:" in err and "runs/001 was made with a different config" in err
    assert files(out) == before
    assert main(["sweep", *TINY_RUN, "--grid", "tracking.lr_trans=0.002", "--out", str(out), "--resume"]) == 2
    assert "runs/001 is a finished run outside this sweep's 1 configs" in capsys.readouterr().err
    assert files(out) == before


def test_a_finished_run_of_another_format_is_refused_saying_what_to_do(tmp_path, uninterrupted, capsys):
    import json
    import shutil

    out = tmp_path / "sweep"
    shutil.copytree(uninterrupted, out)
    config = out / "runs" / "001" / "config.json"
    config.write_text(json.dumps({k: v for k, v in json.loads(config.read_text()).items() if k != "format"}))
    before = files(out)
    assert main([*SWEEP, "--out", str(out), "--resume"]) == 2
    assert "runs/001 was written by another gsjax (run folder format 1; this gsjax writes and resumes format 2): " \
           "run it again with --overwrite, or into a new --out" in capsys.readouterr().err
    assert files(out) == before
