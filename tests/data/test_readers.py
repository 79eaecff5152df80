"""Readers on tiny fixtures in every layout: frames, poses, intrinsics and timestamps come back as written."""

from __future__ import annotations

import json
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.camera import make_intrinsics
from gsjax.data import DatasetError, DatasetWarning, Frame, open_sequence, write_tum
from gsjax.data.tum import FREIBURG_INTRINSICS, associate
from tests.support.recordings import tiny_scene, write_replica, write_scannet, write_sevenscenes, write_tum_by_hand

WRITERS = {"replica": write_replica, "scannet": write_scannet, "7scenes": write_sevenscenes}
DEPTH_SCALES = {"replica": 6553.5, "scannet": 1000.0, "7scenes": 1000.0, "tum": 5000.0}


@pytest.fixture(scope="module")
def scene():
    return tiny_scene(count=4)


def _open(dataset, tmp_path, scene, **options):
    if dataset == "tum":
        folder = write_tum_by_hand(tmp_path, scene)
        return open_sequence("tum", folder, intrinsics=scene[0], **options)
    return open_sequence(dataset, WRITERS[dataset](tmp_path, scene), **options)


@pytest.mark.parametrize("dataset", ["tum", "replica", "scannet", "7scenes"])
def test_reader_returns_written_frames_poses_and_intrinsics(dataset, tmp_path, scene):
    intrinsics, colors, depths, c2w = scene
    seq = _open(dataset, tmp_path, scene)
    assert len(seq) == 4
    k = seq.intrinsics
    assert (k.height, k.width) == (intrinsics.height, intrinsics.width)
    values = lambda i: [float(i.fx), float(i.fy), float(i.cx), float(i.cy)]  # noqa: E731
    np.testing.assert_allclose(values(k), values(intrinsics), rtol=1e-6)
    for i, frame in enumerate(seq):
        assert frame.color.dtype == jnp.float32 and frame.depth.dtype == jnp.float32
        assert frame.color.shape == (intrinsics.height, intrinsics.width, 3)
        np.testing.assert_allclose(np.asarray(frame.color), colors[i] / 255.0, atol=1e-6)
        np.testing.assert_allclose(np.asarray(frame.depth), depths[i], atol=0.5 / DEPTH_SCALES[dataset] + 1e-6)
        np.testing.assert_allclose(np.asarray(frame.c2w), c2w[i], atol=1e-6)
        assert bool(frame.pose_valid) and int(frame.index) == i
    times, poses, valid = seq.gt_trajectory()
    assert times.dtype == np.float64 and poses.dtype == np.float64 and valid.all()
    np.testing.assert_allclose(poses, c2w, atol=1e-8)
    if dataset != "tum":
        np.testing.assert_array_equal(times, [0.0, 1.0, 2.0, 3.0])  # frame numbers where there are no timestamps
    else:
        np.testing.assert_allclose(np.diff(times), 1 / 30.0, atol=2e-6)


def test_gt_trajectory_reads_no_image(tmp_path, scene):
    seq = _open("7scenes", tmp_path, scene)
    for path in (tmp_path / "seq-01").glob("*.png"):
        path.unlink()
    times, poses, valid = seq.gt_trajectory()
    np.testing.assert_allclose(poses, scene[3], atol=1e-8)
    with pytest.raises(DatasetError, match="missing"):
        seq[0]


def test_start_stride_and_max_frames_select_frames(tmp_path, scene):
    seq = _open("7scenes", tmp_path, scene, start=1, stride=2, max_frames=5)
    np.testing.assert_array_equal(seq.timestamps, [1.0, 3.0])
    np.testing.assert_allclose(np.asarray(seq[1].c2w), scene[3][3], atol=1e-6)
    assert int(seq[1].index) == 1 and int(seq[-1].index) == 1
    assert len(_open("replica", tmp_path / "r", scene, max_frames=3)) == 3


def test_sequence_index_out_of_range_raises_index_error(tmp_path, scene):
    seq = _open("7scenes", tmp_path, scene)
    with pytest.raises(IndexError):
        seq[4]
    assert len(list(seq)) == 4


def test_chunks_stack_frames_for_scan(tmp_path, scene):
    seq = _open("7scenes", tmp_path, scene)
    chunks = list(seq.chunks(3))
    assert [c.depth.shape[0] for c in chunks] == [3, 1]
    assert chunks[0].color.shape == (3, scene[0].height, scene[0].width, 3)
    np.testing.assert_array_equal(np.asarray(chunks[1].index), [3])

    def step(total, frame: Frame):
        return total + jnp.sum(frame.depth), frame.index

    total, indices = jax.lax.scan(step, jnp.float32(0.0), chunks[0])
    np.testing.assert_array_equal(np.asarray(indices), [0, 1, 2])
    np.testing.assert_allclose(float(total), sum(float(jnp.sum(seq[i].depth)) for i in range(3)), rtol=1e-5)


def test_scannet_resizes_colour_to_depth_size_and_flags_inf_poses(tmp_path, scene):
    folder = write_scannet(tmp_path, scene)
    (folder / "pose" / "2.txt").write_text("-inf -inf -inf -inf\n" * 4)
    with pytest.warns(DatasetWarning, match=r"pose/2\.txt: pose has non-finite values; left out of the evaluation"):
        seq = open_sequence("scannet", folder)
    assert seq[0].color.shape == seq[0].depth.shape + (3,)
    np.testing.assert_allclose(np.asarray(seq[0].color), scene[1][0] / 255.0, atol=1e-6)
    _, poses, valid = seq.gt_trajectory()
    np.testing.assert_array_equal(valid, [True, True, False, True])
    np.testing.assert_array_equal(poses[2], np.eye(4))
    assert not bool(seq[2].pose_valid)
    np.testing.assert_array_equal(np.asarray(seq[2].c2w), np.eye(4))


def test_scannet_colour_intrinsics_are_rescaled_to_depth_size(tmp_path, scene):
    folder = write_scannet(tmp_path, scene, color_factor=2)
    (folder / "intrinsic" / "intrinsic_depth.txt").unlink()
    k = scene[0]
    fx, cx = 2 * float(k.fx), 2 * float(k.cx) + 0.5  # the colour camera at twice the size, same physical pixels
    color_k = np.eye(4)
    color_k[0, 0], color_k[1, 1], color_k[0, 2], color_k[1, 2] = fx, 2 * float(k.fy), cx, 2 * float(k.cy) + 0.5
    (folder / "intrinsic" / "intrinsic_color.txt").write_text("\n".join(" ".join(map(str, r)) for r in color_k))
    seq = open_sequence("scannet", folder)
    np.testing.assert_allclose([seq.intrinsics.fx, seq.intrinsics.cx, seq.intrinsics.cy], [k.fx, k.cx, k.cy], rtol=1e-6)


def test_sevenscenes_missing_pose_file_flags_frame_and_65535_is_invalid(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    (folder / "frame-000001.pose.txt").unlink()
    import cv2

    raw = cv2.imread(str(folder / "frame-000000.depth.png"), cv2.IMREAD_UNCHANGED)
    raw[0, :5] = 65535
    cv2.imwrite(str(folder / "frame-000000.depth.png"), raw)
    seq = open_sequence("7scenes", folder)
    np.testing.assert_array_equal(seq.gt_trajectory()[2], [True, False, True, True])
    np.testing.assert_array_equal(np.asarray(seq[0].depth)[0, :5], 0.0)
    assert np.all(np.asarray(seq[0].depth)[1] > 0)


def test_sevenscenes_without_intrinsics_file_uses_the_nominal_camera(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    (folder / "camera-intrinsics.txt").unlink()
    k = open_sequence("7scenes", folder).intrinsics
    assert k.shape == scene[0].shape  # from the first depth image
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], [585.0, 585.0, 320.0, 240.0])


def test_write_tum_keeps_missing_poses_missing(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    (folder / "frame-000002.pose.txt").unlink()
    converted = open_sequence("tum", write_tum(open_sequence("7scenes", folder), tmp_path / "as_tum"))
    _, poses, valid = converted.gt_trajectory()
    np.testing.assert_array_equal(valid, [True, True, False, True])
    np.testing.assert_allclose(poses[valid], scene[3][valid], atol=1e-6)
    np.testing.assert_allclose(np.asarray(converted[3].depth), scene[2][3], atol=0.5 / 1000 + 0.5 / 5000 + 1e-6)


def test_replica_defaults_to_nice_slam_camera_without_cam_params(tmp_path, scene):
    folder = write_replica(tmp_path, scene, with_cam_params=False)
    seq = open_sequence("replica", folder)
    k = seq.intrinsics
    assert (k.width, k.height) == (1200, 680)
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], [600.0, 600.0, 599.5, 339.5])


def test_replica_frames_beyond_traj_lines_are_flagged(tmp_path, scene):
    folder = write_replica(tmp_path, scene)
    lines = (folder / "traj.txt").read_text().splitlines()
    (folder / "traj.txt").write_text("\n".join(lines[:3]) + "\n")
    np.testing.assert_array_equal(open_sequence("replica", folder).gt_trajectory()[2], [True, True, True, False])


def test_tum_associates_depth_and_nearest_groundtruth(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    seq = open_sequence("tum", folder, intrinsics=scene[0])
    rgb_stamps = [float(line.split()[0]) for line in (folder / "rgb.txt").read_text().splitlines()[1:]]
    np.testing.assert_allclose(seq.timestamps, rgb_stamps, rtol=0, atol=1e-6)
    np.testing.assert_allclose(seq.gt_trajectory()[1], scene[3], atol=1e-6)  # not the "9 9 9" sample 13 ms later


def test_tum_frame_without_groundtruth_nearby_is_flagged_not_dropped(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    (folder / "groundtruth.txt").write_text("\n".join(lines[:1] + lines[3:]) + "\n")  # frame 0's samples removed
    seq = open_sequence("tum", folder, intrinsics=scene[0])
    assert len(seq) == 4
    np.testing.assert_array_equal(seq.gt_trajectory()[2], [False, True, True, True])
    (folder / "groundtruth.txt").unlink()
    assert not open_sequence("tum", folder, intrinsics=scene[0]).gt_trajectory()[2].any()


def test_tum_colour_frames_without_depth_are_skipped_with_a_warning(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    lines = (folder / "depth.txt").read_text().splitlines()
    (folder / "depth.txt").write_text("\n".join(lines[:2] + lines[3:]) + "\n")  # no depth for frame 1
    with pytest.warns(DatasetWarning, match=r"rgb\.txt: 1 of 4 colour frames have no depth image"):
        seq = open_sequence("tum", folder, intrinsics=scene[0])
    np.testing.assert_allclose(seq.gt_trajectory()[1], scene[3][[0, 2, 3]], atol=1e-6)


def test_tum_association_is_one_to_one_by_smallest_difference():
    rgb = np.array([0.0, 0.010, 0.033, 0.1])
    depth = np.array([0.012, 0.034, 0.5])
    i, j = associate(rgb, depth, 0.02)
    # 0.010 and 0.0 both want depth 0.012; 0.010 is nearer and wins; 0.1 and depth 0.5 have no partner.
    np.testing.assert_array_equal(i, [1, 2])
    np.testing.assert_array_equal(j, [0, 1])


@pytest.mark.parametrize("name, camera", [("rgbd_dataset_freiburg1_desk", 1), ("fr3_office", 3), ("freiburg2", 2)])
def test_tum_intrinsics_follow_the_freiburg_camera_in_the_directory_name(tmp_path, scene, name, camera):
    folder = write_tum_by_hand(tmp_path, scene, name=name)
    k = open_sequence("tum", folder).intrinsics
    assert (k.width, k.height) == (640, 480)
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], FREIBURG_INTRINSICS[camera], rtol=1e-6)


def test_tum_intrinsics_json_takes_precedence_over_the_directory_name(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    (folder / "intrinsics.json").write_text(json.dumps({"fx": 30.0, "fy": 31.0, "cx": 15.5, "cy": 11.5}))
    seq = open_sequence("tum", folder)
    k = seq.intrinsics
    assert (k.width, k.height) == (32, 24)  # from the first colour image, as the JSON gives no size
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], [30.0, 31.0, 15.5, 11.5])
    override = make_intrinsics(40.0, 40.0, 16.0, 12.0, 24, 32)
    assert float(open_sequence("tum", folder, intrinsics=override).intrinsics.fx) == 40.0


def test_open_sequence_rejects_unknown_dataset_and_bad_options(tmp_path, scene):
    folder = write_sevenscenes(tmp_path, scene)
    with pytest.raises(ValueError, match="unknown dataset 'nyu'"):
        open_sequence("nyu", folder)
    with pytest.raises(ValueError, match="stride must be an int >= 1"):
        open_sequence("7scenes", folder, stride=0)
    with pytest.raises(ValueError, match="downscale factor must be a positive int"):
        open_sequence("7scenes", folder, downscale=1.5)


def test_tum_lists_out_of_order_are_sorted_and_repeats_dropped_with_warnings_naming_the_list(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    lines = (folder / "rgb.txt").read_text().splitlines()
    lines[1], lines[3] = lines[3], lines[1]  # frames 2, 1, 0, 3
    (folder / "rgb.txt").write_text("\n".join(lines + [lines[2]]) + "\n")  # frame 1 listed again on line 6
    with pytest.warns(DatasetWarning) as caught:
        seq = open_sequence("tum", folder, intrinsics=scene[0])
    messages = [str(w.message) for w in caught]
    assert len(messages) == 2
    assert re.search(r"rgb\.txt:3: timestamps out of order .* sorted", messages[0]), messages
    assert re.search(r"rgb\.txt:6: timestamp .* listed more than once", messages[1]), messages
    np.testing.assert_allclose(seq.gt_trajectory()[1], scene[3], atol=1e-6)  # the original order, each once
    assert len(seq) == 4


def test_tum_depth_images_without_a_colour_frame_are_skipped_with_a_warning(tmp_path, scene):
    folder = write_tum_by_hand(tmp_path, scene)
    with open(folder / "depth.txt", "a") as handle:
        handle.write("1305031200.0 depth/extra.png\n")
    with pytest.warns(DatasetWarning, match=r"depth\.txt: 1 of 5 depth images have no colour frame"):
        assert len(open_sequence("tum", folder, intrinsics=scene[0])) == 4


@pytest.mark.parametrize("dataset", ["tum", "replica", "scannet", "7scenes"])
def test_intrinsics_as_pinhole_values_and_depth_scale_override_the_dataset(tmp_path, scene, dataset):
    writer = {"tum": write_tum_by_hand, "replica": write_replica, "scannet": write_scannet,
              "7scenes": write_sevenscenes}[dataset]
    folder = writer(tmp_path, scene)
    reference = open_sequence(dataset, folder, intrinsics=scene[0] if dataset == "tum" else None)
    seq = open_sequence(dataset, folder, intrinsics=(20.0, 21.0, 15.0, 11.0), depth_scale=2 * reference.depth_scale)
    k = seq.intrinsics
    assert (k.width, k.height) == (32, 24)  # the stored depth images' size
    np.testing.assert_allclose([k.fx, k.fy, k.cx, k.cy], [20.0, 21.0, 15.0, 11.0])
    np.testing.assert_allclose(np.asarray(seq[1].depth), np.asarray(reference[1].depth) / 2, rtol=1e-6)
    assert seq.depth_scale == 2 * reference.depth_scale
    assert seq.frame_files(1)[1].is_file() and seq.frame_files(1)[0].is_file()
    with pytest.raises(ValueError, match="depth_scale must be a finite number > 0"):
        open_sequence(dataset, folder, depth_scale=0.0)


@pytest.mark.parametrize("dataset, colour", [("replica", "results/frame000001.png"), ("scannet", "color/1.png"),
                                             ("7scenes", "frame-000001.color.png")])
def test_a_depth_image_without_its_colour_image_is_an_error_naming_the_colour_file(tmp_path, scene, dataset, colour):
    writer = {"replica": write_replica, "scannet": write_scannet, "7scenes": write_sevenscenes}[dataset]
    folder = writer(tmp_path, scene)
    (folder / colour).unlink()
    with pytest.raises(DatasetError, match=re.escape(str(folder / colour)) + r": colour image is missing \(its depth"):
        open_sequence(dataset, folder)
