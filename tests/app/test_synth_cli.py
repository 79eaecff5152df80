"""`gsjax synth`: writes a synthetic sequence in the TUM layout; user errors exit with status 2 and one line."""

from __future__ import annotations

from gsjax.app.cli import main
from gsjax.data import open_sequence


def test_cli_synth_writes_a_readable_tum_sequence_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "synth"
    assert main(["synth", "--out", str(out), "--frames", "2", "--seed", "5"]) == 0
    seq = open_sequence("tum", out)
    assert len(seq) == 2 and seq.intrinsics.shape == (120, 160)
    assert (seq[0].depth > 0).all()  # clean: the closed room leaves no invalid pixel
    assert main(["synth", "--out", str(tmp_path / "noisy"), "--frames", "1", "--noise"]) == 0
    assert (open_sequence("tum", tmp_path / "noisy")[0].depth == 0).any()  # holes at depth edges
    assert main(["synth", "--out", str(out), "--frames", "2"]) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert main(["synth", "--out", str(tmp_path / "other"), "--frames", "0"]) == 2
    assert "--frames must be >= 1" in capsys.readouterr().err
