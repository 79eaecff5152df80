"""The output-directory rules: a new or empty directory is used, a previous run only with --resume or
--overwrite, anything else never; the checks write nothing and --overwrite removes gsjax's own outputs only; a
directory a live run holds is refused, and the lock of a killed run blocks nothing."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from gsjax.app.cli import main
from gsjax.app.run_folder.layout import (
    LOCK,
    RunDirError,
    check_run_dir,
    clear_previous_run,
    holder,
    locked_run_dir,
)
from gsjax.io.run_folder import RUN_FILES


def previous_run(out):
    (out / "checkpoints" / "8").mkdir(parents=True)
    (out / "config.json").write_text("{}")
    (out / "renders").mkdir()
    (out / "renders" / "frame_000000.png").write_bytes(b"png")
    return out


def test_new_and_empty_directories_are_usable(tmp_path):
    check_run_dir(tmp_path / "a" / "b" / "run")
    check_run_dir(tmp_path)
    check_run_dir(tmp_path, resume=True)  # a resume with nothing to resume starts afresh
    assert list(tmp_path.iterdir()) == []


def test_a_previous_run_needs_resume_or_overwrite(tmp_path):
    out = previous_run(tmp_path / "run")
    with pytest.raises(RunDirError, match=r"holds a previous run \(config.json, checkpoints/, renders/\); nothing "
                                          r"was changed: pass --resume .* --overwrite"):
        check_run_dir(out)
    check_run_dir(out, resume=True)
    check_run_dir(out, overwrite=True)
    with pytest.raises(RunDirError, match="exclude each other"):
        check_run_dir(out, resume=True, overwrite=True)


@pytest.mark.parametrize("resume, overwrite", [(False, False), (True, False), (False, True)])
def test_a_directory_holding_other_things_is_never_used(tmp_path, resume, overwrite):
    (tmp_path / "thesis.tex").write_text("x")
    with pytest.raises(RunDirError, match="is not empty and holds no gsjax run"):
        check_run_dir(tmp_path, resume=resume, overwrite=overwrite)


def test_files_in_the_way_are_reported(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(RunDirError, match="is an existing file, not a directory"):
        check_run_dir(tmp_path / "file")
    with pytest.raises(RunDirError, match=r"cannot be created: .*file is a file"):
        check_run_dir(tmp_path / "file" / "deeper" / "run")


def test_overwrite_removes_only_gsjax_outputs(tmp_path):
    out = previous_run(tmp_path)
    (out / "notes.txt").write_text("mine")
    assert clear_previous_run(out) == ["config.json", "checkpoints", "renders"]
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert "notes.txt" not in RUN_FILES


# ------------------------------------------------------------------------------ one process per directory

HOLD = ("import sys\nfrom gsjax.app.run_folder.layout import locked_run_dir\nwith locked_run_dir(sys.argv[1]):\n"
        "    print('held', flush=True)\n    sys.stdin.readline()\n")


def holding_process(out):
    """Another process that holds ``out``'s lock until its stdin closes (or it is killed)."""
    process = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               text=True)
    assert process.stdout.readline().strip() == "held"
    return process


def snapshot(out):
    return {p.relative_to(out): (p.stat().st_mtime_ns, p.read_bytes() if p.is_file() else None)
            for p in sorted(out.rglob("*"))}


@pytest.mark.parametrize("argv", [
    ["run", "--resume"],
    ["run", "--overwrite"],
    ["sweep", "--overwrite", "--grid", "tracking.lr_trans=0.001,0.002"],
    ["landscape", "--overwrite", "--frame", "1"],
], ids=["run-resume", "run-overwrite", "sweep", "landscape"])
def test_a_command_into_a_directory_a_live_run_holds_is_refused_touching_nothing(tmp_path, capsys, argv):
    out = previous_run(tmp_path / "run")
    process = holding_process(out)
    try:
        before = snapshot(out)
        assert holder(out) == process.pid
        status = main([argv[0], "--dataset", "synthetic", "--max-frames", "2", "--out", str(out), *argv[1:]])
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 2 and len(err) == 1, err
        assert f"is in use by a running gsjax (process {process.pid}); nothing was changed" in err[0]
        assert snapshot(out) == before
        with pytest.raises(RunDirError, match="in use"), locked_run_dir(out):
            pass
    finally:
        process.stdin.close()
        process.wait(30)
    assert holder(out) is None  # released when the holder ends


def test_a_lock_left_by_a_killed_run_blocks_nothing(tmp_path):
    out = previous_run(tmp_path / "run")
    process = holding_process(out)
    process.send_signal(signal.SIGKILL)
    process.wait(30)
    assert (out / LOCK).is_file() and holder(out) is None
    check_run_dir(out, resume=True)
    with locked_run_dir(out):
        assert holder(out) is not None  # this process's own lock, as another process would see it
    check_run_dir(tmp_path / "fresh")
    with locked_run_dir(tmp_path / "fresh"):
        pass
    check_run_dir(tmp_path / "fresh")  # the lock file alone is no previous run and not "other things"
