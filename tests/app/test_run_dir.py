"""The output-directory rules: a new or empty directory is used, a previous run only with --resume or
--overwrite, anything else never; the checks write nothing and --overwrite removes gsjax's own outputs only."""

from __future__ import annotations

import pytest

from gsjax.app.run_dir import RUN_OUTPUTS, RunDirError, check_run_dir, clear_previous_run


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
    assert "notes.txt" not in RUN_OUTPUTS
