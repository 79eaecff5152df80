"""`gsjax eval`: metrics printed and written as JSON; user errors are one line with exit status 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.config.names import DATASETS
from gsjax.data import READERS
from gsjax.eval.trajectory import evaluate_trajectory
from gsjax.io.trajectory import read_tum_trajectory, write_tum_trajectory
from tests.support.recordings import (
    shared_data,
    tiny_scene,
    write_replica,
    write_scannet,
    write_sevenscenes,
    write_tum_by_hand,
)


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
    assert metrics["ate_rmse_c2w_m"] == pytest.approx(expected.ate_rmse_c2w_m, rel=1e-12)
    assert metrics["ate_splatam_mean_w2c_cm"] == pytest.approx(expected.ate_splatam_mean_w2c_cm, rel=1e-12)
    assert metrics["num_evaluated"] == 40
    printed = capsys.readouterr().out
    assert "ate_rmse_c2w_cm" in printed and "ate_splatam_mean_w2c_cm" in printed and str(out) in printed
    assert (tmp_path / "p" / "trajectory_top.png").stat().st_size > 1000
    assert (tmp_path / "p" / "ate_over_time.png").stat().st_size > 1000


def test_eval_takes_a_run_folder_for_its_trajectory(tmp_path, capsys):
    est, gt = make_files(tmp_path)  # tmp_path/trajectory.txt, as a run's folder holds it
    assert main(["eval", "--est", str(tmp_path), "--gt", str(gt), "--out", str(tmp_path / "folder.json")]) == 0
    assert main(["eval", "--est", str(est), "--gt", str(gt), "--out", str(tmp_path / "file.json")]) == 0
    by_folder, by_file = (json.loads((tmp_path / name).read_text()) for name in ("folder.json", "file.json"))
    assert by_folder == by_file
    (tmp_path / "empty").mkdir()
    assert main(["eval", "--est", str(tmp_path / "empty"), "--gt", str(gt)]) == 2
    assert "a folder without trajectory.txt (not a finished gsjax run)" in capsys.readouterr().err


def test_eval_defaults_the_output_next_to_the_estimate_and_honours_max_dt(tmp_path, capsys):
    est, gt = make_files(tmp_path)
    assert main(["eval", "--est", str(est), "--gt", str(gt), "--max-dt", "0.001"]) == 2  # 3 ms offset: no match
    assert "no estimated pose" in capsys.readouterr().err
    assert main(["eval", "--est", str(est), "--gt", str(gt), "--scale"]) == 0
    metrics = json.loads((tmp_path / "trajectory.metrics.json").read_text())
    assert metrics["with_scale"] is True and metrics["alignment"]["scale"] != 1.0


def test_eval_with_a_gt_directory_but_no_dataset_is_a_user_error(tmp_path, capsys):
    est, _ = make_files(tmp_path)
    assert main(["eval", "--est", str(est), "--gt", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gsjax eval: error:") and "needs --dataset" in err and "is a directory" in err


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


def test_eval_dataset_choices_are_the_readers():
    assert tuple(READERS) == DATASETS  # one list of names (gsjax.config.names), in one order


WRITERS = {"tum": write_tum_by_hand, "replica": write_replica, "scannet": write_scannet, "7scenes": write_sevenscenes}


@pytest.mark.parametrize("dataset", DATASETS)
def test_eval_reads_the_gt_of_a_dataset_directory(tmp_path, capsys, dataset):
    scene = tiny_scene(count=5)
    folder = WRITERS[dataset](tmp_path / "data", scene)
    if dataset == "tum":  # the frames' timestamps are their colour stamps
        stamps = np.array([float(line.split()[0]) for line in (folder / "rgb.txt").read_text().splitlines()[1:]])
    else:  # the frame numbers
        stamps = np.arange(5.0)
    if dataset == "7scenes":
        (folder / "frame-000003.pose.txt").unlink()  # a frame without GT: skipped, not scored
    est = scene[3].copy()
    est[:, :3, 3] += 0.01 * np.random.default_rng(0).standard_normal((5, 3))
    write_tum_trajectory(tmp_path / "est.txt", stamps, est)
    out = tmp_path / "metrics.json"
    args = ["eval", "--est", str(tmp_path / "est.txt"), "--gt", str(folder), "--dataset", dataset, "--out", str(out)]
    assert main(args + ["--plots", str(tmp_path / "plots")]) == 0
    metrics = json.loads(out.read_text())
    valid = np.arange(5) != 3 if dataset == "7scenes" else np.ones(5, bool)
    expected = evaluate_trajectory(stamps, est, stamps, scene[3], gt_valid=valid)
    assert metrics["gt_dataset"] == dataset and metrics["num_associated"] == 5
    assert metrics["num_evaluated"] == valid.sum() and metrics["num_skipped_invalid_gt"] == 5 - valid.sum()
    assert metrics["ate_rmse_c2w_m"] == pytest.approx(expected.ate_rmse_c2w_m, rel=1e-6)
    assert metrics["ate_splatam_mean_w2c_m"] == pytest.approx(expected.ate_splatam_mean_w2c_m, rel=1e-6)
    assert (tmp_path / "plots" / "trajectory_top.png").stat().st_size > 1000


def test_eval_with_dataset_but_a_gt_file_is_a_user_error(tmp_path, capsys):
    est, gt = make_files(tmp_path)
    assert main(["eval", "--est", str(est), "--gt", str(gt), "--dataset", "tum"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gsjax eval: error:") and "--dataset tum needs --gt DIR" in err


def test_eval_reports_a_dataset_directory_it_cannot_read(tmp_path, capsys):
    est, _ = make_files(tmp_path)
    (tmp_path / "empty").mkdir()
    assert main(["eval", "--est", str(est), "--gt", str(tmp_path / "empty"), "--dataset", "scannet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gsjax eval: error:") and str(tmp_path / "empty" / "color") in err


SEVENSCENES = shared_data() / "7scenes_redkitchen"


@pytest.mark.skipif(not SEVENSCENES.is_dir(), reason=f"{SEVENSCENES} not present")
def test_eval_against_7scenes_associates_an_estimate_stamped_with_frame_numbers(tmp_path):
    gt = np.stack([np.loadtxt(SEVENSCENES / f"frame-{i:06d}.pose.txt") for i in range(150)])
    world = np.eye(4)  # the estimate lives in another world frame: the alignment must undo it
    world[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    world[:3, 3] = [1.0, -2.0, 0.5]
    est = world @ gt
    write_tum_trajectory(tmp_path / "est.txt", np.arange(150), est)
    out = tmp_path / "metrics.json"
    args = ["eval", "--est", str(tmp_path / "est.txt"), "--gt", str(SEVENSCENES), "--dataset", "7scenes"]
    assert main(args + ["--out", str(out)]) == 0
    metrics = json.loads(out.read_text())
    assert metrics["num_associated"] == 150 and metrics["num_evaluated"] == 150
    assert metrics["ate_rmse_c2w_m"] < 1e-9  # camera centres go through the TUM file exactly
    # Rotations do not: the file's quaternions are exactly rigid, 7-Scenes' matrices only to ~1.5e-4 (gsjax.data.poses),
    # which moves w2c translations (-R^T c) by well under 0.1 mm and relative rotations by well under 0.001 deg.
    assert metrics["ate_splatam_mean_w2c_m"] < 1e-4 and metrics["rpe_rot_rmse_deg"] < 1e-3
