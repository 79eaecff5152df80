"""`gsjax eval`: metrics printed and written as JSON; user errors are one line with exit status 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gsjax.cli import main
from gsjax.eval.trajectory import evaluate_trajectory
from gsjax.io.trajectory import read_tum_trajectory, write_tum_trajectory


def make_files(tmp_path, n=40):
    rng = np.random.default_rng(0)
    s = np.linspace(0, np.pi, n)
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, :3, 3] = np.stack([np.cos(s), 0.1 * s, np.sin(s)], 1)
    est = gt.copy()
    est[:, :3, 3] += 0.01 * rng.standard_normal((n, 3))
    write_tum_trajectory(tmp_path / "gt.txt", 100 + 0.1 * np.arange(n), gt)
    write_tum_trajectory(tmp_path / "trajectory.txt", 100 + 0.1 * np.arange(n) + 0.003, est)
    return tmp_path / "trajectory.txt", tmp_path / "gt.txt"


def test_eval_writes_the_metrics_json_and_prints_them(tmp_path, capsys):
    est, gt = make_files(tmp_path)
    out = tmp_path / "res" / "metrics.json"
    assert main(["eval", "--est", str(est), "--gt", str(gt), "--out", str(out), "--plots", str(tmp_path / "p")]) == 0
    metrics = json.loads(out.read_text())
    expected = evaluate_trajectory(*read_tum_trajectory(est), *read_tum_trajectory(gt), max_dt=0.02)
    assert metrics["ate_rmse_c2w_m"] == pytest.approx(expected["ate_rmse_c2w_m"], rel=1e-12)
    assert metrics["ate_splatam_mean_w2c_cm"] == pytest.approx(expected["ate_splatam_mean_w2c_cm"], rel=1e-12)
    assert metrics["num_evaluated"] == 40
    printed = capsys.readouterr().out
    assert "ate_rmse_c2w_cm" in printed and "ate_splatam_mean_w2c_cm" in printed and str(out) in printed
    assert (tmp_path / "p" / "trajectory_top.png").stat().st_size > 1000
    assert (tmp_path / "p" / "ate_over_time.png").stat().st_size > 1000


def test_eval_defaults_the_output_next_to_the_estimate_and_honours_max_dt(tmp_path, capsys):
    est, gt = make_files(tmp_path)
    assert main(["eval", "--est", str(est), "--gt", str(gt), "--max-dt", "0.001"]) == 2  # 3 ms offset: no match
    assert "no estimated pose" in capsys.readouterr().err
    assert main(["eval", "--est", str(est), "--gt", str(gt), "--scale"]) == 0
    metrics = json.loads((tmp_path / "trajectory.metrics.json").read_text())
    assert metrics["with_scale"] is True and metrics["alignment"]["scale"] != 1.0


def test_eval_with_a_gt_directory_is_a_user_error_until_datasets_are_wired(tmp_path, capsys):
    est, _ = make_files(tmp_path)
    assert main(["eval", "--est", str(est), "--gt", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gsjax eval: error:") and "needs --dataset; not yet supported" in err


def test_eval_reports_a_bad_trajectory_line_with_file_and_line(tmp_path, capsys):
    est, gt = make_files(tmp_path)
    with open(est, "a") as f:
        f.write("999 1 2 3\n")
    assert main(["eval", "--est", str(est), "--gt", str(gt)]) == 2
    err = capsys.readouterr().err
    assert f"{est}:42:" in err and "expected 8 numbers" in err


def test_eval_with_a_missing_file_is_a_user_error(tmp_path, capsys):
    _, gt = make_files(tmp_path)
    assert main(["eval", "--est", str(tmp_path / "nope.txt"), "--gt", str(gt)]) == 2
    assert "no such file" in capsys.readouterr().err
