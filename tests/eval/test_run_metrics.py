"""metrics.json's typed record: the JSON round trip, older files, and errors that name the key."""

import json

import pytest

from gsjax.eval.run_metrics import (
    CBKNNSummary,
    CheckpointSummary,
    RenderMetrics,
    RunMetrics,
    TrajectoryMetrics,
    read_run_metrics,
)


def a_record() -> RunMetrics:
    return RunMetrics(
        dataset="synthetic", frames=3, width=8, height=6,
        trajectory=TrajectoryMetrics(ate_rmse_c2w_m=0.01, ate_rmse_c2w_cm=1.0, rpe_rot_rmse_deg=None,
                                     per_frame=dict(est_index=[0, 1, 2], ate_c2w_m=[0.0, 0.01, 0.02])),
        constant_pose_ate_rmse_c2w_cm=4.5,
        render=RenderMetrics(frames=[0, 2], mean=dict(psnr_db=30.5, depth_l1_cm=1.25),
                             per_frame=[dict(psnr_db=30.0), dict(psnr_db=31.0)]),
        cbknn=CBKNNSummary(mode="paper", alpha=0.2, k0=5.0, beta=0.3, cell=8, samples=[dict(frame=0, gamma=0.1)]),
        stage_timings_s=dict(slam_s=1.5), checkpoints=CheckpointSummary(2, 3, 0.1, 0.2, 100, 120),
        warnings=["w"], skipped_frames=[], keyframe_frames=[0], per_frame=dict(tracking_loss=[0.0, None, 1.0]))


def test_a_record_round_trips_through_json_with_its_keys_in_field_order(tmp_path):
    record = a_record()
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps(record.to_json()))
    back = read_run_metrics(path)
    assert back == record
    assert list(json.loads(path.read_text()))[:4] == ["dataset", "frames", "width", "height"]
    assert (back.ate_cm, back.psnr_db) == (1.0, 30.5)
    assert back.render.at(2) == dict(psnr_db=31.0) and back.render.at(1) is None


def test_an_older_file_reads_back_with_defaults_and_newer_keys_are_ignored():
    old = RunMetrics.from_json(dict(frames=4, trajectory=None, render=dict(frames=[], mean=None), future_key=1))
    assert old.frames == 4 and old.trajectory is None and old.ate_cm is None and old.psnr_db is None
    assert old.warnings == [] and old.checkpoints is None and old.render.per_frame == []


@pytest.mark.parametrize("value, message", [
    (dict(width=3), "has no 'frames'"),
    (dict(frames=1, render=[1]), "'render' expected a JSON object, got list"),
    (dict(frames=1, trajectory=dict(ate_rmse_c2w_m=0.1)), "'trajectory' has no 'ate_rmse_c2w_cm'"),
])
def test_a_malformed_record_is_refused_naming_the_key(value, message):
    with pytest.raises(ValueError, match=message):
        RunMetrics.from_json(value)


def test_reading_a_damaged_file_names_it(tmp_path):
    path = tmp_path / "metrics.json"
    path.write_text("{not json")
    with pytest.raises(ValueError, match=f"{path}: cannot be read as JSON"):
        read_run_metrics(path)
    path.write_text("[]")
    with pytest.raises(ValueError, match=f"{path}: expected a JSON object, got list"):
        read_run_metrics(path)
