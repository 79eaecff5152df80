"""The studies' bookkeeping (experiments/studies.py): finished sweeps are kept and reused, earlier results carried."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "experiments"))
import studies


def _finish(out: Path, rows: list[dict], wall: float) -> None:
    """What a finished `gsjax sweep --out out` leaves: sweep.csv and sweep.json."""
    out.mkdir(parents=True)
    with open(out / "sweep.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (out / "sweep.json").write_text(json.dumps({"wall_s": wall}))


@pytest.fixture
def runs(tmp_path, monkeypatch):
    monkeypatch.setattr(studies, "RUNS", tmp_path / "results" / "runs")
    monkeypatch.setattr(studies, "ROOT", tmp_path)
    launched = []
    monkeypatch.setattr(studies.subprocess, "run", lambda command, **_: launched.append(command))
    return launched


def test_a_kept_sweep_is_reused_when_the_work_folder_is_gone(tmp_path, runs):
    rows = [{"cbknn.mode": "off", "seed": "0", "ate_rmse_cm": "0.5"},
            {"cbknn.mode": "paper", "seed": "0", "ate_rmse_cm": "0.6"}]
    _finish(tmp_path / "work" / "a", rows, wall=12.4)
    argv = ["--dataset", "synthetic", "--seeds", "1"]
    log: list[str] = []
    assert studies.sweep(tmp_path / "work", "a", argv, log, keep="study") == rows
    assert log[-1].endswith("(wall 12 s; rows kept in results/runs/study/a.csv)") and runs == []
    (tmp_path / "work" / "a" / "sweep.csv").unlink()
    (tmp_path / "work" / "a" / "sweep.json").unlink()

    assert studies.sweep(tmp_path / "work", "a", argv, log, keep="study") == rows
    assert "(wall 12 s; rows kept in results/runs/study/a.csv)" in log[-1] and runs == []


def test_a_kept_sweep_of_another_command_runs_again(tmp_path, runs):
    _finish(tmp_path / "work" / "a", [{"seed": "0", "ate_rmse_cm": "0.5"}], wall=3.0)
    studies.sweep(tmp_path / "work", "a", ["--seeds", "1"], [], keep="study")
    (tmp_path / "work" / "a" / "sweep.csv").unlink()
    with pytest.raises(FileNotFoundError):  # the fake launch finishes nothing
        studies.sweep(tmp_path / "work", "a", ["--seeds", "2"], [], keep="study")
    assert len(runs) == 1 and runs[0][-3:] == ["--seeds", "2", "--overwrite"]


def test_carried_over_keeps_the_rows_not_produced_again_and_their_commands(tmp_path):
    result = tmp_path / "r.csv"
    result.write_text("# command: python experiments/robustness.py\n"
                      "# ran: gsjax sweep --out /w/seq_map --seeds 5\n"
                      "# ran: gsjax sweep --out /w/seq_depth --seeds 5\n"
                      "# ran: wall time of seq_map (its sweep.json): 20 s\n"
                      "# ran: gsjax sweep --out /w/seq_stride --seeds 5  (wall 9 s; rows kept in results/runs/s.csv)\n"
                      "sequence,factor,mode,ate\nseq,map,off,1.0\nseq,depth,off,2.0\nseq,stride,off,3.0\n")
    fresh = [{"sequence": "seq", "factor": "depth", "mode": "off", "ate": "2.5"}]
    commands, rows = studies.carried_over(result, ["sequence", "factor", "mode"], fresh,
                                          lambda r: f"{r['sequence']}_{r['factor']}")
    assert rows == [{"sequence": "seq", "factor": "map", "mode": "off", "ate": "1.0"},
                    {"sequence": "seq", "factor": "stride", "mode": "off", "ate": "3.0"}]
    assert commands == [studies.EARLIER + "gsjax sweep --out /w/seq_map --seeds 5",
                        studies.EARLIER + "wall time of seq_map (its sweep.json): 20 s",
                        studies.EARLIER_KEPT + "gsjax sweep --out /w/seq_stride --seeds 5  (wall 9 s; rows kept in "
                                               "results/runs/s.csv)"]
    # written back as "# ran:" lines and carried again, the marker is not repeated
    result.write_text("".join(f"# ran: {c}\n" for c in commands)
                      + "sequence,factor,mode,ate\nseq,map,off,1.0\nseq,stride,off,3.0\n")
    again, _ = studies.carried_over(result, ["sequence", "factor", "mode"], fresh,
                                    lambda r: f"{r['sequence']}_{r['factor']}")
    assert again == commands
    assert studies.carried_over(tmp_path / "missing.csv", ["sequence"], fresh, str) == ([], [])


def test_each_robustness_row_names_the_sweep_it_came_from():
    import robustness

    def name(factor, level, mode="paper"):
        return robustness.sweep_name({"sequence": "s", "factor": factor, "level": level, "mode": mode})

    assert name("clean", "") == name("map_noise_cm", "1") == "s_map"
    assert name("map_noise_cm", "2") == name("map_noise_cm", "3") == "s_map_strong"
    assert name("persistent_noise_cm", "2") == "s_persistent"
    assert name("stride", "4") == "s_stride4" and name("stride", "4", mode="blur") == "s_stride4_blur"
