"""`gsjax run`: a tiny synthetic run writes every output; user errors exit with status 2 and one line."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.app.run_folder.checkpoints import Checkpoints
from gsjax.config.text import config_to_dict
from gsjax.io.ply import read_ply
from gsjax.io.trajectory import read_tum_trajectory
from tests.support.tiny_slam import FRAMES, HEIGHT, TINY_OVERRIDES, TINY_RUN, WIDTH, tiny_config, tiny_sequence

# --downscale 4 turns the default 160x120 synthetic room into 40x30; with these options the CLI builds exactly the
# program the other SLAM tests compile (tiny_config, FRAMES frames, chunks of CHUNK).

@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    assert main(["run", "--out", str(out)] + TINY_RUN) == 0
    return out


def test_cli_run_writes_a_tum_trajectory_with_one_line_per_frame_at_the_dataset_timestamps(cli_run):
    lines = [x for x in (cli_run / "trajectory.txt").read_text().splitlines() if x and not x.startswith("#")]
    assert len(lines) == FRAMES and all(len(x.split()) == 8 for x in lines)
    stamps, c2w = read_tum_trajectory(cli_run / "trajectory.txt")
    gt_stamps, gt_c2w, _ = tiny_sequence().gt_trajectory()
    np.testing.assert_allclose(stamps, gt_stamps, atol=1e-6)
    # Written in the dataset's world frame: frame 0 (the SLAM origin) sits on its ground-truth pose.
    np.testing.assert_allclose(c2w[0], gt_c2w[0], atol=1e-5)
    assert np.all(np.isfinite(c2w))


def test_cli_run_writes_metrics_with_trajectory_image_speed_and_config_entries(cli_run):
    metrics = json.loads((cli_run / "metrics.json").read_text())
    trajectory = metrics["trajectory"]
    for key in ("ate_rmse_c2w_cm", "ate_splatam_mean_w2c_cm", "rpe_trans_rmse_m", "rpe_rot_rmse_deg"):
        assert np.isfinite(trajectory[key]), key
    assert trajectory["num_evaluated"] == FRAMES
    render = metrics["render"]
    assert render["frames"] == [0, 4]  # t = 0 and (t + 1) % 5 == 0
    for key in ("psnr_db", "ssim", "ms_ssim", "depth_l1_cm"):
        assert np.isfinite(render["mean"][key]), key
    assert render["mean"]["psnr_db"] > 10
    assert metrics["frames_per_s"] > 0 and metrics["seconds_per_frame"] > 0
    assert {"read_frames_s", "slam_s", "checkpoint_s", "regrow_s", "outputs_s"} <= set(metrics["stage_timings_s"])
    assert metrics["num_gaussians"] >= WIDTH * HEIGHT and metrics["capacity"] == 2 * WIDTH * HEIGHT
    assert (metrics["frames"], metrics["width"], metrics["height"]) == (FRAMES, WIDTH, HEIGHT)
    assert metrics["nonfinite_tracking_iterations"] == 0
    assert metrics["config"] == config_to_dict(tiny_config())


def test_cli_run_writes_plots_renders_a_readable_map_config_and_checkpoints(cli_run):
    png = b"\x89PNG\r\n\x1a\n"
    assert (cli_run / "trajectory.png").read_bytes()[:8] == png
    renders = sorted(p.name for p in (cli_run / "renders").iterdir())
    assert renders == ["frame_000000.png", "frame_000004.png"]
    assert all((cli_run / "renders" / name).read_bytes()[:8] == png for name in renders)
    metrics = json.loads((cli_run / "metrics.json").read_text())
    gaussians = read_ply(cli_run / "map.ply")
    assert gaussians.capacity == metrics["num_gaussians"] and bool(gaussians.active.all())
    config = json.loads((cli_run / "config.json").read_text())
    assert config["dataset"] == "synthetic" and config["downscale"] == 4
    assert config["overrides"] == TINY_OVERRIDES and config["config"] == metrics["config"]
    checkpoints = Checkpoints(cli_run / "checkpoints")
    try:
        assert checkpoints.latest() == FRAMES
        assert checkpoints.read_ledger(FRAMES).frames_done == FRAMES
    finally:
        checkpoints.close()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--dataset", "synthetic", "--tracking.nope", "1"], r"--tracking\.nope: unknown field 'nope'"),
        (["--dataset", "synthetic", "--tracking.iters", "abc"], r"--tracking\.iters: cannot read 'abc' as int"),
        (["--dataset", "synthetic", "--tracking.iters", "0"], r"tracking\.iters must be an int >= 1"),
        (["--dataset", "synthetic", "--cbknn.params.alpha", "-1"], r"CBKNN\.alpha must be a finite number >= 0 \(px\)"),
        (["--dataset", "synthetic", "--tracking.iters"], r"--tracking\.iters needs a value"),
        (["--dataset", "synthetic", "--verbose"], r"unrecognised argument '--verbose'"),
        (["--dataset", "synthetic", "--downscale", "7"], r"--downscale 7 must divide the synthetic 160x120 image"),
        (["--dataset", "tum"], r"--dataset tum needs --path DIR"),
        (["--dataset", "replica", "--path", "/nonexistent/gsjax"], r"--path /nonexistent/gsjax: no such directory"),
    ],
)
def test_cli_run_user_errors_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, args, message):
    out = tmp_path / "run"
    assert main(["run", "--out", str(out)] + args) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gsjax run: error: "), captured.err
    assert re.search(message, lines[0]), lines[0]
    assert not out.exists()
