"""``config.json`` as a typed record: the layout round-trips key for key, older files read back, resume's key."""

from __future__ import annotations

import json

import pytest

from gsjax.eval.run_input import RESUME_KEYS, RUN_FORMAT, RunInput, read_run_input

CAMERA = dict(fx=30.0, fy=30.0, cx=19.5, cy=14.5, width=40, height=30, depth_scale=5000.0)
FILE = dict(format=2, dataset="tum", path="/data/room", preset="cpu", cbknn="off", overrides={"tracking.iters": "3"},
            sequence="room", frames=6, width=40, height=30, chunk=3, seed=0, camera=CAMERA,
            config={"keyframe_every": 5}, sweep=dict(values={"tracking.lr_trans": "0.003"}, batch=0, batch_size=1))


def test_a_config_json_reads_back_and_writes_the_same_object_in_the_same_order():
    record = RunInput.from_json(FILE)
    assert record.describe == dict(dataset="tum", path="/data/room", preset="cpu", cbknn="off",
                                   overrides={"tracking.iters": "3"}, sequence="room")
    assert (record.frames, record.width, record.height, record.chunk, record.seed) == (6, 40, 30, 3, 0)
    assert record.camera == CAMERA and record.sweep["batch_size"] == 1
    assert list(record.to_json().items()) == list(FILE.items())
    alone = {k: v for k, v in FILE.items() if k != "sweep"}  # a run's: no sweep entry, not even null
    assert list(RunInput.from_json(alone).to_json()) == list(alone)


def test_an_older_file_reads_back_with_none_and_resume_compares_size_chunk_seed_camera_and_config(tmp_path):
    older = {k: v for k, v in FILE.items() if k not in ("format", "camera", "sweep")}
    (tmp_path / "config.json").write_text(json.dumps(older))
    record = read_run_input(tmp_path / "config.json")
    assert record.camera is None and record.sweep is None and record.format is None
    assert RunInput.from_json(FILE).format == RUN_FORMAT == 2
    assert list(record.resume_key()) == list(RESUME_KEYS) and record.resume_key()["camera"] is None
    assert RunInput.from_json(FILE).resume_key() == {k: FILE[k] for k in RESUME_KEYS}


def test_a_file_that_is_not_a_config_json_is_an_error_naming_it(tmp_path):
    for text in ("[1, 2]", "{not json"):
        (tmp_path / "config.json").write_text(text)
        with pytest.raises(ValueError, match=r"config\.json: cannot be read as a run's config.json"):
            read_run_input(tmp_path / "config.json")
