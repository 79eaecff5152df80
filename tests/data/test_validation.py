"""Every reader check fails with a DatasetError whose message names the offending file and the problem."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest

from gsjax.camera import make_intrinsics
from gsjax.data import DatasetError, DatasetWarning, open_sequence
from tests.support.recordings import tiny_scene, write_replica, write_scannet, write_sevenscenes, write_tum_by_hand


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(count=3)


def _raises(path, problem):
    """pytest.raises for a DatasetError whose message contains the path and the problem (a regex)."""
    return pytest.raises(DatasetError, match=re.escape(str(path)) + ".*" + problem)


def test_dataset_error_is_a_value_error():
    assert issubclass(DatasetError, ValueError)


def test_missing_depth_image_is_reported_at_open(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    (folder / "frame-000001.depth.png").unlink()
    with _raises(folder / "frame-000001.depth.png", "image is missing"):
        open_sequence("7scenes", folder)


def test_missing_sequence_directory_is_reported(tmp_path):
    with _raises(tmp_path / "nowhere", "directory is missing"):
        open_sequence("replica", tmp_path / "nowhere")


def test_unreadable_colour_image_is_reported_when_the_frame_is_read(tmp_path, scene):
    folder = write_replica(tmp_path, scene)
    (folder / "results" / "frame000002.png").write_bytes(b"not a png at all")
    seq = open_sequence("replica", folder)
    seq[1]
    with _raises(folder / "results" / "frame000002.png", "cannot be read"):
        seq[2]


def test_colour_and_depth_size_mismatch_is_reported(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    cv2.imwrite(str(folder / "frame-000000.color.png"), np.zeros((20, 30, 3), np.uint8))
    problem = r"colour image is 30x20 .* depth image frame-000000.depth.png is 32x24"
    with _raises(folder / "frame-000000.color.png", problem):
        open_sequence("7scenes", folder)[0]


def test_depth_size_differing_from_the_intrinsics_is_reported(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    wrong = make_intrinsics(30.0, 30.0, 20.0, 15.0, height=30, width=40)
    with _raises(folder / "frame-000000.depth.png", "depth image is 32x24 .*, the intrinsics expect 40x30"):
        open_sequence("7scenes", folder, intrinsics=wrong)[0]


def test_tum_without_any_depth_association_is_reported(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene, depth_offset=0.5)
    with _raises(folder / "depth.txt", "no depth association"):
        open_sequence("tum", folder, intrinsics=scene[0])


def _tum_with_float_depth(tmp_path, scene, values):
    folder = write_tum_by_hand(tmp_path, scene)
    depth = scene[2][0].astype(np.float32) * 5000.0
    depth[3, 4] = values
    path = folder / "depth" / "float.tiff"
    assert cv2.imwrite(str(path), depth)
    lines = (folder / "depth.txt").read_text().splitlines()
    lines[1] = lines[1].split()[0] + " depth/float.tiff"
    (folder / "depth.txt").write_text("\n".join(lines) + "\n")
    return open_sequence("tum", folder, intrinsics=scene[0]), path


def test_float_depth_images_are_accepted_and_scaled(tmp_path, scene):
    seq, _ = _tum_with_float_depth(tmp_path, scene, 0.0)
    expected = scene[2][0].copy()
    expected[3, 4] = 0.0
    np.testing.assert_allclose(np.asarray(seq[0].depth), expected, rtol=1e-6)


def test_non_finite_depth_is_reported(tmp_path, scene):
    seq, path = _tum_with_float_depth(tmp_path, scene, np.nan)
    with _raises(path, "1 non-finite values"):
        seq[0]


def test_negative_depth_is_reported(tmp_path, scene):
    seq, path = _tum_with_float_depth(tmp_path, scene, -1.0)
    with _raises(path, "1 negative values"):
        seq[0]


def test_eight_bit_depth_is_reported(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    cv2.imwrite(str(folder / "frame-000000.depth.png"), np.full((24, 32), 9, np.uint8))
    with _raises(folder / "frame-000000.depth.png", "must be 16-bit unsigned or float, got uint8"):
        open_sequence("7scenes", folder, intrinsics=scene[0])[0]


def test_unparsable_tum_groundtruth_line_is_reported_with_its_line_number(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    with open(folder / "groundtruth.txt", "a") as handle:
        handle.write("1305031103.0 0 0 zero 0 0 0 1\n")
    n = len((folder / "groundtruth.txt").read_text().splitlines())
    with _raises(f"{folder / 'groundtruth.txt'}:{n}", "cannot parse numbers"):
        open_sequence("tum", folder, intrinsics=scene[0])


def test_unparsable_tum_file_list_timestamp_is_reported(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    (folder / "rgb.txt").write_text("# colour\nnoon rgb/x.png\n")
    with _raises(f"{folder / 'rgb.txt'}:2", "cannot parse timestamp 'noon'"):
        open_sequence("tum", folder, intrinsics=scene[0])


def test_replica_traj_line_with_wrong_count_is_reported(tmp_path, scene):
    folder = write_replica(tmp_path, scene)
    lines = (folder / "traj.txt").read_text().splitlines()
    lines[1] = " ".join(lines[1].split()[:15])
    (folder / "traj.txt").write_text("\n".join(lines) + "\n")
    with _raises(f"{folder / 'traj.txt'}:2", "expected 16 numbers, got 15"):
        open_sequence("replica", folder)


def test_sevenscenes_pose_file_with_a_short_row_is_reported(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    (folder / "frame-000002.pose.txt").write_text("1 0 0 0\n0 1 0\n0 0 1 0\n0 0 0 1\n")
    with _raises(f"{folder / 'frame-000002.pose.txt'}:2", "expected 4 numbers, got 3"):
        open_sequence("7scenes", folder)


def _warns(path, problem):
    """pytest.warns for a DatasetWarning whose message contains the path and the problem (a regex)."""
    return pytest.warns(DatasetWarning, match=re.escape(str(path)) + ".*" + problem)


def test_non_rigid_pose_matrix_is_left_out_of_the_evaluation_with_a_warning(tmp_path, scene):
    folder = write_scannet(tmp_path, scene)
    scaled = scene[3][1].copy()
    scaled[:3, :3] *= 1.1
    (folder / "pose" / "1.txt").write_text("\n".join(" ".join(map(str, row)) for row in scaled) + "\n")
    with _warns(folder / "pose" / "1.txt", r"pose is not a rigid transform .*left out of the evaluation \(1 such"):
        seq = open_sequence("scannet", folder)
    np.testing.assert_array_equal(seq.gt_trajectory()[2], [True, False, True])
    np.testing.assert_array_equal(seq.gt_trajectory()[1][1], np.eye(4))


def test_non_finite_pose_matrix_is_left_out_of_the_evaluation_with_a_warning(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    (folder / "frame-000002.pose.txt").write_text("-inf -inf -inf -inf\n" * 4)
    with _warns(folder / "frame-000002.pose.txt", r"non-finite values; left out of the evaluation"):
        seq = open_sequence("7scenes", folder)
    np.testing.assert_array_equal(seq.gt_trajectory()[2], [True, True, False])


def test_tum_groundtruth_samples_not_unit_or_not_finite_are_left_out_with_a_warning(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    lines[3] = f"{lines[3].split()[0]} 0 0 0 0 0 0 2"  # frame 1's nearest sample (line 4) ...
    lines[4] = f"{lines[4].split()[0]} nan 0 0 0 0 0 1"  # ... and the one 13 ms later (line 5)
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with _warns(f"{folder / 'groundtruth.txt'}:4", r"pose is not a rigid transform \(quaternion norm 2"), \
            _warns(f"{folder / 'groundtruth.txt'}:5", r"pose has non-finite values; left out of the evaluation"):
        seq = open_sequence("tum", folder, intrinsics=scene[0])
    np.testing.assert_array_equal(seq.gt_trajectory()[2], [True, False, True])


@pytest.mark.parametrize("dataset", ["replica", "scannet", "7scenes", "tum"])
def test_empty_sequence_is_reported(tmp_path, scene, dataset):
    if dataset == "tum":
        folder = write_tum_by_hand(tmp_path, scene)
        (folder / "rgb.txt").write_text("# color images\n# timestamp filename\n")
        where = folder / "rgb.txt"
    else:
        writer = {"replica": write_replica, "scannet": write_scannet, "7scenes": write_sevenscenes}[dataset]
        folder = writer(tmp_path, scene)
        images = folder / {"replica": "results", "scannet": "color", "7scenes": ""}[dataset]
        for path in images.glob("*.png"):
            path.unlink()
        where = images
    with _raises(where, "empty sequence"):
        open_sequence(dataset, folder, intrinsics=scene[0])


def test_start_past_the_end_is_an_empty_sequence(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    with _raises(folder, r"empty sequence \(3 frames listed, none left from start=3\)"):
        open_sequence("7scenes", folder, start=3)


def test_tum_without_determinable_intrinsics_is_reported(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene, name="kitchen_walk")
    with _raises(folder, "cannot determine the camera intrinsics"):
        open_sequence("tum", folder)


def test_malformed_intrinsics_json_is_reported(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    (folder / "intrinsics.json").write_text(json.dumps({"fx": 30.0, "fy": 30.0, "cx": 15.5}))
    with _raises(folder / "intrinsics.json", "cannot read fx, fy, cx, cy"):
        open_sequence("tum", folder)


def test_non_pinhole_calibration_matrix_is_reported(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    (folder / "camera-intrinsics.txt").write_text("25 3 16\n0 25 12\n0 0 1\n")
    with _raises(folder / "camera-intrinsics.txt", "not a pinhole calibration matrix"):
        open_sequence("7scenes", folder)


def test_two_files_for_one_frame_number_are_reported(tmp_path, scene):
    folder = write_replica(tmp_path, scene)
    (folder / "results" / "frame000001.jpg").write_bytes((folder / "results" / "frame000001.png").read_bytes())
    with _raises(folder / "results", "two files for frame 1: frame000001"):
        open_sequence("replica", folder)
