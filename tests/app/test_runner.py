"""The runner shell (``run_slam``): capacity growth re-runs chunks and changes nothing (beyond float32 rounding),
a resumed run equals the uninterrupted one bit for bit, and resuming with other options is refused."""

from __future__ import annotations

import copy
import json
import os
import shutil

import numpy as np
import pytest

from gsjax.app.run_folder.checkpoints import Checkpoints
from gsjax.app.run_folder.layout import holder
from gsjax.app.session.recorder import compile_estimate
from gsjax.app.session.runner import run_slam
from gsjax.config.text import apply_overrides
from gsjax.eval.run_metrics import read_run_metrics
from gsjax.io.ply import read_ply
from gsjax.io.trajectory import read_tum_trajectory
from tests.support.tiny_slam import CAPACITY, CHUNK, FRAMES, run_options, tiny_config, tiny_sequence

OUTPUTS = ("trajectory.txt", "map.ply")


def saved_outputs(out):
    """The per-frame outputs (every StepOutputs field, full float32 precision) of the newest checkpoint, by name as
    lists (compared whole with ==)."""
    checkpoints = Checkpoints(out / "checkpoints")
    try:
        return {name: values.tolist() for name, values in checkpoints.outputs(checkpoints.latest())._asdict().items()}
    finally:
        checkpoints.close()


def assert_same_run(out, metrics, reference_out, reference_metrics):
    """Bit for bit the same trajectory, map and per-frame outputs, and the same evaluation."""
    for name in OUTPUTS:
        assert (out / name).read_bytes() == (reference_out / name).read_bytes(), name
    assert saved_outputs(out) == saved_outputs(reference_out)
    for key in ("trajectory", "render", "num_gaussians", "capacity", "keyframes", "nonfinite_tracking_iterations"):
        assert getattr(metrics, key) == getattr(reference_metrics, key), key


def assert_close_run(out, metrics, reference_out, reference_metrics):
    """The same run up to float32 rounding: poses within 1e-5 m / 1e-5, the same Gaussians (count, keyframes,
    per-frame counts), and per-frame outputs and metrics within 1e-4 relative."""
    _, c2w = read_tum_trajectory(out / "trajectory.txt")
    _, c2w_ref = read_tum_trajectory(reference_out / "trajectory.txt")
    np.testing.assert_allclose(c2w, c2w_ref, atol=1e-5)
    got, want = read_ply(out / "map.ply"), read_ply(reference_out / "map.ply")
    assert got.capacity == want.capacity
    np.testing.assert_allclose(np.asarray(got.means), np.asarray(want.means), atol=1e-4)
    outputs, reference_outputs = saved_outputs(out), saved_outputs(reference_out)
    assert outputs.keys() == reference_outputs.keys()
    for name in outputs:
        np.testing.assert_allclose(np.asarray(outputs[name], np.float64),
                                   np.asarray(reference_outputs[name], np.float64), rtol=1e-4, atol=1e-5, err_msg=name)
    for key in ("num_gaussians", "capacity", "keyframes", "nonfinite_tracking_iterations"):
        assert getattr(metrics, key) == getattr(reference_metrics, key), key
    ate, reference_ate = metrics.trajectory.ate_rmse_c2w_m, reference_metrics.trajectory.ate_rmse_c2w_m
    assert ate == pytest.approx(reference_ate, abs=1e-5)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted run with the default capacity (2 H W, enough for the whole sequence)."""
    out = tmp_path_factory.mktemp("reference")
    return out, run_slam(tiny_sequence(), tiny_config(), run_options(out))


def test_metrics_json_reads_back_as_the_record_the_run_returned(reference):
    out, metrics = reference
    assert read_run_metrics(out / "metrics.json") == metrics


class Interrupt(Exception):
    pass


def interrupt(frames_done):
    raise Interrupt(frames_done)


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory):
    """A run stopped by an exception right after its first checkpoint (frame CHUNK); tests work on copies."""
    out = tmp_path_factory.mktemp("interrupted")
    with pytest.raises(Interrupt):
        run_slam(tiny_sequence(), tiny_config(), run_options(out), on_chunk=interrupt)
    return out


def copy_of(run_dir, tmp_path):
    return shutil.copytree(run_dir, tmp_path / "run")


def test_a_tiny_capacity_grows_by_rerunning_chunks_and_changes_nothing(tmp_path, capsys, reference):
    """Capacity 1200 = the 1200 Gaussians of frame 0: a later chunk's new Gaussians find no free slot, and it is re-run
    at 2400 (the default capacity, whose program the other tests compile). The trajectory, map and every per-frame
    output are those of a run started at 2400, up to float32 rounding: the chunks before ran a program compiled for
    another capacity, which XLA may fuse (and so round) differently. (A lone render is bit for bit independent of the
    capacity; inside the whole SLAM step it is not guaranteed.)"""
    out = tmp_path / "small"
    metrics = run_slam(tiny_sequence(), tiny_config(), run_options(out, capacity=CAPACITY // 2))
    log = capsys.readouterr().out
    assert "growing the map to 2400 slots and re-running the chunk" in log
    assert log.count("growing the map") == 1
    assert metrics.capacity == CAPACITY
    assert not any(saved_outputs(out)["dropped"])
    assert metrics.stage_timings_s["regrow_s"] > 0
    assert_close_run(out, metrics, *reference)


def test_resume_after_an_interruption_reproduces_the_uninterrupted_run(tmp_path, interrupted, reference):
    out = copy_of(interrupted, tmp_path)
    checkpoints = Checkpoints(out / "checkpoints")
    assert checkpoints.latest() == CHUNK
    checkpoints.close()
    assert not (out / "trajectory.txt").exists()
    metrics = run_slam(tiny_sequence(), tiny_config(), run_options(out, resume=True))
    assert_same_run(out, metrics, *reference)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(seed=1), "different seed"),
        (dict(chunk=2), "different chunk"),
        (dict(config={"tracking.lr_trans": "0.003"}), "different config"),
        (dict(frames=FRAMES - 1), "different frames"),
    ],
)
def test_resuming_with_different_options_is_a_value_error_naming_the_option(tmp_path, interrupted, change, message):
    out = copy_of(interrupted, tmp_path)
    config = apply_overrides(tiny_config(), change.pop("config", {}))
    sequence = tiny_sequence(change.pop("frames", FRAMES))
    with pytest.raises(ValueError, match=rf"--resume: the checkpoint in .* was made with a {message} .*new --out"):
        run_slam(sequence, config, run_options(out, resume=True, **change))


def test_a_refused_resume_leaves_the_run_directory_unchanged(tmp_path, interrupted):
    out = copy_of(interrupted, tmp_path)
    before = (out / "config.json").read_bytes()
    with pytest.raises(ValueError):
        run_slam(tiny_sequence(), tiny_config(), run_options(out, resume=True, seed=1))
    assert json.loads((out / "config.json").read_bytes()) == json.loads(before)


def test_a_run_folder_of_another_format_is_refused_saying_what_to_do_and_left_unchanged(tmp_path, interrupted):
    """Checkpoints whose ledger holds another run folder format (gsjax before issue 48 wrote none) are not resumed and
    not fallen back past: the resume stops, naming the folder and --overwrite, and changes nothing."""
    out = copy_of(interrupted, tmp_path)
    ledgers = [path for path in (out / "checkpoints").rglob("*") if path.is_file() and b'"frames_done"' in
               path.read_bytes()]
    assert ledgers
    for path in ledgers:
        value = json.loads(path.read_text())
        del value["format"]
        path.write_text(json.dumps(value))
    before = {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file() and p.name != ".gsjax.lock"}
    with pytest.raises(ValueError, match=r"--resume: .* was written by another gsjax \(run folder format 1; this gsjax "
                                         r"writes and resumes format 2\): run it again with --overwrite"):
        run_slam(tiny_sequence(), tiny_config(), run_options(out, resume=True))
    assert {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file() and p.name != ".gsjax.lock"} == before


def test_frames_per_second_after_a_resume_covers_the_whole_run(tmp_path, interrupted):
    out = copy_of(interrupted, tmp_path)
    before = dict(_checkpoint_ledger(out).timings)  # the interrupted session's SLAM time
    metrics = run_slam(tiny_sequence(), tiny_config(), run_options(out, resume=True))
    # Timings are carried through the checkpoint: the SLAM time spans both sessions, and so does the rate.
    assert metrics.stage_timings_s["slam_s"] > before["slam_s"] > 0
    assert metrics.frames_per_s == pytest.approx(FRAMES / metrics.stage_timings_s["slam_s"])


def _checkpoint_ledger(out):
    from gsjax.app.run_folder.checkpoints import Checkpoints

    checkpoints = Checkpoints(out / "checkpoints")
    try:
        return checkpoints.read_ledger(checkpoints.latest())
    finally:
        checkpoints.close()


def test_a_run_holds_its_directory_while_it_runs_and_lets_go_after(tmp_path):
    out = tmp_path / "run"
    seen = []
    run_slam(tiny_sequence(), tiny_config(), run_options(out), on_chunk=lambda done: seen.append(holder(out)))
    assert seen == [os.getpid()] * (FRAMES // CHUNK)
    assert holder(out) is None


def test_a_run_reads_each_frame_once(tmp_path):
    """The evaluation renders compare with the frames the chunk loop read (the next chunk is read while one runs):
    no frame is read twice, but frame 0, read once more before anything is written (to fail early)."""
    sequence = copy.copy(tiny_sequence())
    reads, read = [], sequence.read_host
    sequence.read_host = lambda i: (reads.append(i), read(i))[1]
    run_slam(sequence, tiny_config(), run_options(tmp_path / "run"))
    assert sorted(reads) == [0, *range(FRAMES)]


def test_the_compile_estimate_counts_the_later_chunks_real_frames_not_their_padding():
    """10 frames in chunks of 8 at 0.5 s a frame, plus 3 s of compilation in the first chunk: the first chunk takes
    7 s, the second (2 real frames, 6 padding) 1 s."""
    assert compile_estimate(7.0, 8.0, 10, 8) == pytest.approx(3.0)
    assert compile_estimate(5.0, 9.0, 16, 8) == pytest.approx(1.0)  # two full chunks: 4 s each, 1 s beyond
    assert compile_estimate(2.0, 2.0, 8, 8) is None and compile_estimate(None, 2.0, 16, 8) is None
    assert compile_estimate(3.0, 11.0, 16, 8) == 0.0  # a first chunk faster than the steady rate: no compilation
