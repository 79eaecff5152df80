"""One way from a finished run to its files: the same config through `gsjax run` and through a one-config `gsjax
sweep` writes the same ``metrics.json`` (timings aside, warnings included) and ``config.json`` (the sweep's own
entry and where the command line put the one value aside), on a recording with a frame the run skips."""

from __future__ import annotations

import json

import cv2
import numpy as np

from gsjax.app.cli import main
from gsjax.data import write_tum
from tests.support.metrics_schema import assert_valid_metrics
from tests.support.tiny_slam import CHUNK, FRAMES, HEIGHT, TINY_OVERRIDES, WIDTH, tiny_sequence

SKIPPED = 3
LR = "0.003"
# What only the process that ran knows: its seconds, and the checkpoints a run writes and a sweep does not.
TIMINGS = ("stage_timings_s", "frames_per_s", "seconds_per_frame", "checkpoints")


def recording_with_a_frame_without_depth(folder):
    data = write_tum(tiny_sequence(), folder)
    lines = [line for line in (data / "depth.txt").read_text().splitlines() if line and not line.startswith("#")]
    cv2.imwrite(str(data / lines[SKIPPED].split()[1]), np.zeros((HEIGHT, WIDTH), np.uint16))
    return data


def test_a_run_and_a_one_config_sweep_write_the_same_metrics_and_config(tmp_path, capsys):
    data = recording_with_a_frame_without_depth(tmp_path / "room")
    common = ["--dataset", "tum", "--path", str(data), "--max-frames", str(FRAMES), "--chunk", str(CHUNK),
              "--no-progress", *[token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]]
    assert main(["run", "--out", str(tmp_path / "run"), *common, "--tracking.lr_trans", LR]) == 0
    assert main(["sweep", "--out", str(tmp_path / "sweep"), *common, "--grid", f"tracking.lr_trans={LR}"]) == 0
    capsys.readouterr()
    swept = tmp_path / "sweep" / "runs" / "000"
    run_metrics, sweep_metrics = (assert_valid_metrics(d / "metrics.json") for d in (tmp_path / "run", swept))
    assert run_metrics["skipped_frames"] == [SKIPPED]
    assert any(f"frame {SKIPPED}" in w and "valid depth" in w for w in sweep_metrics["warnings"])
    for key in TIMINGS:
        run_metrics.pop(key), sweep_metrics.pop(key)
    assert sweep_metrics == run_metrics
    run_config, sweep_config = (json.loads((d / "config.json").read_text()) for d in (tmp_path / "run", swept))
    values = sweep_config.pop("sweep")["values"]
    assert values == {"tracking.lr_trans": LR}
    # The command lines differ in one place: the run's override is the sweep's grid value.
    assert {**sweep_config.pop("overrides"), **values} == run_config.pop("overrides")
    assert sweep_config == run_config
