"""`gsjax tune`: its files (tuned.json, tune.csv, tune.png), `gsjax run --tuned`, and bad input refused by name."""

from __future__ import annotations

import csv
import json

import pytest

from gsjax.app.cli import main
from tests.support.tiny_slam import TINY_OVERRIDES

FRAMES = 3
RUN = ["--dataset", "synthetic", "--downscale", "4", "--max-frames", str(FRAMES), "--no-progress",
       *[token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]]
PARAMS = "tracking.lr_trans,tracking.lambda_color"


@pytest.fixture(scope="module")
def tuned_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune") / "t"
    assert main(["tune", "--out", str(out), *RUN, "--params", PARAMS, "--tracking.lr_trans", "3e-4",
                 "--steps", "2", "--objective", "ate"]) == 0
    return out


def test_tune_writes_its_steps_and_the_lowest_objectives_fields(tuned_dir):
    rows = list(csv.DictReader((tuned_dir / "tune.csv").open()))
    assert [int(r["step"]) for r in rows] == [0, 1, 2]
    assert {"objective", "tracking.lr_trans", "tracking.lambda_color", "d_tracking.lr_trans",
            "d_tracking.lambda_color"} <= set(rows[0])
    assert float(rows[0]["tracking.lr_trans"]) == pytest.approx(3e-4)  # the start given on the command line
    assert float(rows[1]["tracking.lr_trans"]) != pytest.approx(3e-4)  # a step was taken
    document = json.loads((tuned_dir / "tuned.json").read_text())
    best = min(rows, key=lambda r: float(r["objective"]))
    assert document["fields"] == pytest.approx({"tracking.lr_trans": float(best["tracking.lr_trans"]),
                                                "tracking.lambda_color": float(best["tracking.lambda_color"])})
    assert document["value"] == pytest.approx(float(best["objective"]))
    assert document["objective"] == "ate" and document["steps"] == 2 and document["frames"] == FRAMES
    assert (tuned_dir / "tune.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_run_applies_a_tuned_json_and_the_command_line_wins(tuned_dir, tmp_path):
    fields = json.loads((tuned_dir / "tuned.json").read_text())["fields"]
    out = tmp_path / "run"
    assert main(["run", "--out", str(out), *RUN, "--tuned", str(tuned_dir / "tuned.json"),
                 "--tracking.lambda_color", "0.25"]) == 0
    config = json.loads((out / "config.json").read_text())["config"]
    assert config["tracking"]["lr_trans"] == pytest.approx(fields["tracking.lr_trans"])
    assert config["tracking"]["lambda_color"] == 0.25


@pytest.mark.parametrize("flags, words", [
    (["--params", "tracking.iters"], "tracking.iters is an integer"),
    (["--params", "raster.tile_size"], "static"),
    (["--params", "tracking.nope"], "unknown field 'tracking.nope'"),
    (["--params", "tracking.lr_trans", "--tracking.lr_trans", "-1"], "tracking.lr_trans must be"),
    (["--params", "tracking.sil_threshold", "--tracking.sil_threshold", "1.5"], "tracking.sil_threshold must be"),
    (["--params", "tracking.lr_trans", "--tracking.lr_trans", "0"], "log scale"),
])
def test_tune_refuses_a_field_it_cannot_tune_naming_it(flags, words, tmp_path, capsys):
    assert main(["tune", "--out", str(tmp_path / "t"), *RUN, *flags]) == 2
    assert words in capsys.readouterr().err
    assert not (tmp_path / "t").exists()


def test_run_refuses_a_tuned_file_it_cannot_read(tmp_path, capsys):
    bad = tmp_path / "tuned.json"
    bad.write_text('{"fields": {"tracking.lr_trans": "fast"}}')
    assert main(["run", "--out", str(tmp_path / "r"), *RUN, "--tuned", str(bad)]) == 2
    assert f"--tuned {bad}" in capsys.readouterr().err
