"""TUM trajectory files: exact round trip, interop with evo, quaternion conventions, errors naming file and line."""

from __future__ import annotations

import numpy as np
import pytest

from gsjax.camera import (
    quaternion_to_rotation_np,
)
from gsjax.io.trajectory import read_tum_trajectory, write_tum_trajectory


def random_c2w(rng, n):
    q = rng.standard_normal((n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    c2w = np.tile(np.eye(4), (n, 1, 1))
    c2w[:, :3, :3] = quaternion_to_rotation_np(q)
    c2w[:, :3, 3] = rng.standard_normal((n, 3))
    return c2w


def test_trajectory_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    stamps = 1305031102.175304 + np.cumsum(rng.uniform(0.01, 0.05, 50))
    c2w = random_c2w(rng, 50)
    write_tum_trajectory(tmp_path / "traj.txt", stamps, c2w)
    stamps2, c2w2 = read_tum_trajectory(tmp_path / "traj.txt")
    np.testing.assert_array_equal(stamps2, stamps)
    np.testing.assert_array_equal(c2w2[:, :3, 3], c2w[:, :3, 3])
    np.testing.assert_allclose(c2w2, c2w, atol=1e-15)


def test_evo_reads_our_files_as_the_same_poses(tmp_path):
    from evo.tools import file_interface
    rng = np.random.default_rng(1)
    c2w = random_c2w(rng, 20)
    write_tum_trajectory(tmp_path / "t.txt", np.arange(20) * 0.1, c2w)
    traj = file_interface.read_tum_trajectory_file(str(tmp_path / "t.txt"))
    np.testing.assert_allclose(np.stack(traj.poses_se3), c2w, atol=1e-12)


def test_reader_skips_comments_blank_lines_and_normalises_quaternions(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text("# ground truth\n\n1.0 1 2 3 0 0 0 2\r\n2.5, 0, 0, 0, 0, 0, 1, 0\n")
    stamps, c2w = read_tum_trajectory(path)
    np.testing.assert_array_equal(stamps, [1.0, 2.5])
    np.testing.assert_allclose(c2w[0], [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]])
    np.testing.assert_allclose(c2w[1, :3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-15)  # 180 deg about z


def test_non_finite_poses_round_trip_as_invalid(tmp_path):
    c2w = random_c2w(np.random.default_rng(3), 3)
    c2w[1] = np.nan
    write_tum_trajectory(tmp_path / "t.txt", [0.0, 1.0, 2.0], c2w)
    _, back = read_tum_trajectory(tmp_path / "t.txt")
    assert np.isnan(back[1]).all() and np.isfinite(back[[0, 2]]).all()


@pytest.mark.parametrize(
    "bad_line, message",
    [
        ("3.0 1 2 3 0 0 0", "expected 8 numbers"),
        ("3.0 1 2 3 0 0 0 1 7", "expected 8 numbers"),
        ("3.0 1 2 x 0 0 0 1", "not a number"),
        ("3.0 1 2 3 0 0 0 0", "zero length"),
        ("0.5 1 2 3 0 0 0 1", "does not increase"),
        ("nan 1 2 3 0 0 0 1", "timestamp must be finite"),
    ],
)
def test_bad_lines_raise_errors_naming_file_and_line(tmp_path, bad_line, message):
    path = tmp_path / "est.txt"
    path.write_text(f"# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n{bad_line}\n")
    with pytest.raises(ValueError, match=message) as info:
        read_tum_trajectory(path)
    assert f"{path}:4:" in str(info.value)


def test_writer_rejects_unordered_timestamps(tmp_path):
    with pytest.raises(ValueError, match="strictly increasing"):
        write_tum_trajectory(tmp_path / "t.txt", [1.0, 1.0], np.stack([np.eye(4)] * 2))
    assert not (tmp_path / "t.txt").exists()
