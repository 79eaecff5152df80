"""3DGS PLY export/import: the exact standard header and record layout, the 3DGS conventions, exact round trip."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.gaussians import Gaussians
from gsjax.io.ply import read_ply, write_ply

STANDARD_HEADER = (
    "ply\n"
    "format binary_little_endian 1.0\n"
    "element vertex 5\n"
    "property float x\nproperty float y\nproperty float z\n"
    "property float nx\nproperty float ny\nproperty float nz\n"
    "property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n"
    "property float opacity\n"
    "property float scale_0\nproperty float scale_1\nproperty float scale_2\n"
    "property float rot_0\nproperty float rot_1\nproperty float rot_2\nproperty float rot_3\n"
    "end_header\n"
).encode("ascii")


def sample_map(n=5, capacity=8, seed=0):
    rng = np.random.default_rng(seed)
    g = Gaussians.create(
        means=rng.standard_normal((n, 3)),
        rgb=rng.uniform(-0.1, 1.1, (n, 3)),  # raw colours may leave [0, 1]
        scales=rng.uniform(0.001, 0.1, n),
        opacities=rng.uniform(0.01, 0.99, n),
        capacity=capacity,
    )
    # garbage in the free slots must not be exported
    return Gaussians(g.means.at[n:].set(99.0), g.log_scales, g.logit_opacities, g.rgb.at[n:].set(7.0), g.active)


def test_written_ply_has_the_exact_standard_header_and_layout(tmp_path):
    g = sample_map()
    write_ply(tmp_path / "map.ply", g)
    data = (tmp_path / "map.ply").read_bytes()
    assert data[: len(STANDARD_HEADER)] == STANDARD_HEADER
    assert len(data) == len(STANDARD_HEADER) + 5 * 17 * 4
    rec = np.frombuffer(data[len(STANDARD_HEADER) :], dtype="<f4").reshape(5, 17)
    c0 = 0.28209479177387814
    np.testing.assert_array_equal(rec[:, 0:3], np.asarray(g.means[:5]))
    np.testing.assert_array_equal(rec[:, 3:6], 0.0)
    np.testing.assert_allclose(0.5 + c0 * rec[:, 6:9], np.asarray(g.rgb[:5]), atol=1e-7)
    np.testing.assert_array_equal(rec[:, 9], np.asarray(g.logit_opacities[:5]))
    for k in range(3):
        np.testing.assert_array_equal(rec[:, 10 + k], np.asarray(g.log_scales[:5]))
    np.testing.assert_array_equal(rec[:, 13:17], np.tile([1.0, 0.0, 0.0, 0.0], (5, 1)))


def test_ply_round_trip_is_exact_up_to_float32(tmp_path):
    g = sample_map()
    write_ply(tmp_path / "map.ply", g)
    back = read_ply(tmp_path / "map.ply", capacity=12)
    assert back.capacity == 12 and int(back.num_active()) == 5
    np.testing.assert_array_equal(np.asarray(back.active), np.arange(12) < 5)
    for field in ("means", "log_scales", "logit_opacities"):
        np.testing.assert_array_equal(np.asarray(getattr(back, field))[:5], np.asarray(getattr(g, field))[:5])
    # rgb goes through f_dc = (rgb - 0.5) / C0 in float32: at most one float32 ulp of change
    np.testing.assert_allclose(np.asarray(back.rgb)[:5], np.asarray(g.rgb)[:5], rtol=0, atol=1.5e-7)
    assert np.all(np.asarray(back.means)[5:] == 0)


def test_an_empty_map_writes_a_valid_empty_file(tmp_path):
    write_ply(tmp_path / "empty.ply", Gaussians.empty(4))
    back = read_ply(tmp_path / "empty.ply")
    assert back.capacity == 0


def test_export_rejects_non_finite_active_gaussians(tmp_path):
    g = sample_map()
    g = Gaussians(g.means.at[2, 0].set(jnp.nan), g.log_scales, g.logit_opacities, g.rgb, g.active)
    with pytest.raises(ValueError, match="means has non-finite"):
        write_ply(tmp_path / "bad.ply", g)
    assert not (tmp_path / "bad.ply").exists()


def _ply(header_lines, body=b""):
    return ("\n".join(["ply", *header_lines, "end_header"]) + "\n").encode() + body


def test_import_accepts_other_property_orders_and_extra_fields(tmp_path):
    names = ["f_dc_0", "f_dc_1", "f_dc_2", "x", "y", "z", "opacity", "scale_0", "f_rest_0"]
    rec = np.array([[0.1, 0.2, 0.3, 1.0, 2.0, 3.0, -1.0, -4.0, 5.0]], "<f4")
    path = tmp_path / "other.ply"
    path.write_bytes(
        _ply(["format binary_little_endian 1.0", "comment from another tool", "element vertex 1",
              *[f"property float {n}" for n in names]], rec.tobytes())
    )
    g = read_ply(path)
    np.testing.assert_array_equal(np.asarray(g.means), [[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(np.asarray(g.rgb), 0.5 + 0.28209479177387814 * rec[:, :3], atol=1e-7)
    assert float(g.log_scales[0]) == -4.0 and float(g.logit_opacities[0]) == -1.0


@pytest.mark.parametrize(
    "header, body, message",
    [
        (["format ascii 1.0", "element vertex 0", "property float x"], b"", "binary_little_endian"),
        (["format binary_little_endian 1.0", "element vertex 0", "property float x"], b"", "missing vertex properties"),
        (["format binary_little_endian 1.0", "element face 0"], b"", "first element must be 'vertex'"),
    ],
)
def test_import_rejects_unsupported_files_naming_them(tmp_path, header, body, message):
    path = tmp_path / "x.ply"
    path.write_bytes(_ply(header, body))
    with pytest.raises(ValueError, match=message) as info:
        read_ply(path)
    assert str(path) in str(info.value)


def test_import_rejects_truncated_and_anisotropic_files(tmp_path):
    write_ply(tmp_path / "map.ply", sample_map())
    data = (tmp_path / "map.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-4])
    with pytest.raises(ValueError, match="truncated"):
        read_ply(tmp_path / "cut.ply")
    rec = np.frombuffer(data[len(STANDARD_HEADER) :], "<f4").reshape(5, 17).copy()
    rec[0, 11] += 0.5  # scale_1 != scale_0
    (tmp_path / "aniso.ply").write_bytes(STANDARD_HEADER + rec.tobytes())
    with pytest.raises(ValueError, match="anisotropic"):
        read_ply(tmp_path / "aniso.ply")
