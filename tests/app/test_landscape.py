"""`gsjax landscape`: its gradients agree with finite differences of its own loss, the basin rule, the JSON
contract (the axes, the tracker's fixed point, the 2-D grid), the modes asked for, and the map built at ground-truth
poses."""

from __future__ import annotations

import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gsjax.app.cli import main
from gsjax.app.runtime.cache import exported_call
from gsjax.data import open_sequence, write_tum
from gsjax.frame import stack_frames, to_device
from gsjax.slam import landscape as pure
from gsjax.slam.driver import run as slam_run
from gsjax.slam.losses import rendered_depth, tracking_mask
from gsjax.slam.presets import with_cbknn_mode
from gsjax.slam.system import run_chunk, unknown_poses
from gsjax.slam.tracking import TrackingProblem, tracking_objective
from tests.support.tiny_slam import (
    CHUNK,
    FRAMES,
    TINY_OVERRIDES,
    relative_gt_w2c,
    replaced,
    tiny_config,
    tiny_sequence,
)

FRAME = 4
STEPS = 3  # offsets -1, 0, 1: the tracker's runs (2 modes x (2 axes x 3 + 3^2 + 1)) are the module's time
# The tiny tests' config (their SLAM program: the counts are traced) with 30 tracking and mapping iterations: the
# tiny runs' 2 mapping iterations leave a map whose loss is not lowest at the ground-truth pose.
COUNTS = {"tracking.iters": 30, "mapping.iters": 30}
OVERRIDES = [token for name, value in {**TINY_OVERRIDES, **COUNTS}.items() for token in (f"--{name}", str(value))]
RUN = ["--dataset", "synthetic", "--downscale", "4", "--chunk", str(CHUNK), *OVERRIDES]


def config():
    return replaced(tiny_config(), COUNTS)


# The axes and their 2-D grid (steps^2 tracker runs more, in the same compiled program as the axes').
LANDSCAPE = ["--frame", str(FRAME), "--steps", str(STEPS), "--axes", "tx,rz", "--extent-cm", "1", "--extent-deg", "1",
             "--map-from", "gt", "--grid2d"]


@pytest.fixture(scope="module")
def landscape_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("landscape") / "l"
    assert main(["landscape", "--out", str(out), *RUN, *LANDSCAPE]) == 0
    return out


def test_landscape_json_has_the_contract_layout(landscape_dir):
    doc = json.loads((landscape_dir / "landscape.json").read_text())
    assert doc["frame"] == FRAME and doc["reference"] == "gt" and list(doc["axes"]) == ["tx", "rz"]
    assert doc["axes"]["tx"]["unit"] == "cm" and doc["axes"]["rz"]["unit"] == "deg"
    np.testing.assert_allclose(doc["axes"]["tx"]["offsets"], np.linspace(-1, 1, STEPS))
    for axis in ("tx", "rz"):
        for mode in ("off", "paper"):
            entry = doc["axes"][axis][mode]
            assert len(entry["loss"]) == len(entry["grad"]) == STEPS
            assert np.all(np.isfinite(entry["loss"])) and np.all(np.isfinite(entry["grad"]))
            assert entry["basin"] >= 0
        # The loss is lowest near the ground-truth pose (the map was built at the GT poses).
        assert int(np.argmin(doc["axes"][axis]["off"]["loss"])) == STEPS // 2
    # paper renders the smoothed keyframe view with its own colour weight: another landscape.
    assert doc["axes"]["tx"]["off"]["loss"] != doc["axes"]["tx"]["paper"]["loss"]
    assert (landscape_dir / "landscape.png").read_bytes()[:4] == b"\x89PNG"


def test_the_fixed_point_is_where_the_tracker_started_at_the_reference_ends(landscape_dir):
    """On the tiny map the tracker started at the ground truth ends away from it (measured 0.89 cm off, 0.68 cm
    paper): basin_fixed counts convergence to that point, basin to the reference."""
    doc = json.loads((landscape_dir / "landscape.json").read_text())
    assert doc["modes"] == ["off", "paper"]
    for mode in ("off", "paper"):
        fixed = doc["fixed_point"][mode]
        assert fixed["error_cm"] > 0.05 and np.asarray(fixed["w2c"]).shape == (4, 4)
        assert sorted(fixed["offsets"]) == sorted(pure.AXES)
        for axis in ("tx", "rz"):
            entry = doc["axes"][axis][mode]
            # The grid point at offset 0 is the reference: the tracker from there is the fixed point.
            assert entry["final_fixed_error_cm"][STEPS // 2] < 1e-3
            assert entry["final_error_cm"][STEPS // 2] == pytest.approx(fixed["error_cm"], abs=1e-3)
            assert entry["converged_fixed"] == pure.converged(entry["final_fixed_error_cm"],
                                                             entry["final_fixed_error_deg"]).tolist()
            assert entry["basin_fixed"] == pure.basin_width(doc["axes"][axis]["offsets"], entry["converged_fixed"])


def test_grid2d_json_holds_the_plane_of_the_two_axes_and_its_heat_map(landscape_dir):
    doc = json.loads((landscape_dir / "landscape.json").read_text())
    plane = doc["grid2d"]
    assert plane["axes"] == ["tx", "rz"] and plane["units"] == ["cm", "deg"]
    assert plane["offsets"] == {axis: doc["axes"][axis]["offsets"] for axis in ("tx", "rz")}
    for mode in ("off", "paper"):
        entry = plane[mode]
        for key in ("loss", "converged", "converged_fixed", "final_error_cm", "final_error_deg",
                    "final_fixed_error_cm", "final_fixed_error_deg"):
            assert np.asarray(entry[key]).shape == (STEPS, STEPS), key
        assert np.all(np.isfinite(entry["loss"]))
        # [i][j] = (tx_i, rz_j): the plane's lines through the reference are the axes' own landscapes.
        np.testing.assert_allclose(np.asarray(entry["loss"])[:, STEPS // 2], doc["axes"]["tx"][mode]["loss"], rtol=1e-5)
        np.testing.assert_allclose(np.asarray(entry["loss"])[STEPS // 2], doc["axes"]["rz"][mode]["loss"], rtol=1e-5)
        for suffix in ("", "_fixed"):
            converged = np.asarray(entry["converged" + suffix])
            assert (entry["basin" + suffix], entry["area" + suffix]) == pure.basin_2d(
                plane["offsets"]["tx"], plane["offsets"]["rz"], converged)
            assert 0 <= entry["basin" + suffix] <= 1
    assert (landscape_dir / "landscape2d.png").read_bytes()[:4] == b"\x89PNG"


def test_modes_are_an_option(tmp_path, landscape_dir):
    """``--modes paper`` evaluates paper alone, exactly as beside off."""
    out = tmp_path / "l"
    assert main(["landscape", "--out", str(out), *RUN, *LANDSCAPE, "--modes", "paper"]) == 0
    doc = json.loads((out / "landscape.json").read_text())
    both = json.loads((landscape_dir / "landscape.json").read_text())
    assert doc["modes"] == ["paper"] and list(doc["fixed_point"]) == ["paper"]
    assert "off" not in doc["axes"]["tx"] and "off" not in doc["grid2d"]
    np.testing.assert_allclose(doc["axes"]["tx"]["paper"]["loss"], both["axes"]["tx"]["paper"]["loss"], rtol=1e-6)


def test_a_mode_is_one_registry_entry(monkeypatch):
    from gsjax.app import landscape as app

    monkeypatch.setitem(app.MODES, "wider", (lambda c: c, False))
    assert app.LandscapeOptions(out="x", frame=1, modes=("off", "wider")).modes == ("off", "wider")
    with pytest.raises(ValueError, match="--modes must name distinct modes among off, paper, blur, pyramid, wider, "
                                         "got off,blurry"):
        app.LandscapeOptions(out="x", frame=1, modes=("off", "blurry"))


def test_the_classic_alternatives_are_tracking_variants_of_off():
    from gsjax.app import landscape as app
    from gsjax.slam.presets import preset

    base = preset("cpu")
    blur, blur_smooth = app.MODES["blur"]
    pyramid, pyramid_smooth = app.MODES["pyramid"]
    blurred, coarse = blur(base).tracking, pyramid(base).tracking
    assert not blur_smooth and not pyramid_smooth
    assert blur(base).cbknn.mode == pyramid(base).cbknn.mode == "off"
    assert (blurred.blur.radius_px, float(blurred.blur.sigma_px), blurred.coarse.iters) == (6, 1.5, 0)
    assert (coarse.coarse.iters, coarse.coarse.levels, float(coarse.blur.sigma_px)) == (20, 2, 0.0)
    # As many iterations per frame as the preset: the coarse ones replace strided ones.
    assert coarse.coarse.iters + coarse.strided_iters + coarse.iters == base.tracking.strided_iters + \
        base.tracking.iters


@functools.lru_cache(maxsize=None)
def _map_and_frame():
    gt = relative_gt_w2c().astype(np.float32)
    # Through the program the module's CLI landscape exported (the direct call gives the same bits: test_programs).
    built = slam_run([tiny_sequence().read_host(i) for i in range(FRAME)], config(), tiny_sequence().intrinsics,
                     poses=gt[:FRAME], chunk=CHUNK, call=exported_call())
    frame = tiny_sequence().read_host(FRAME)
    return built.state.gaussians, jnp.asarray(frame.color), jnp.asarray(frame.depth), jnp.asarray(gt[FRAME])


# mode -> (config, relative tolerance). In paper mode the smoothed render's loss is piecewise at a fine scale (every
# change of a pixel's K nearest contributors is a small jump, and the shift direction (C - u) / |C - u| carries no
# gradient by design: its Jacobian is singular where a centre sits on the centroid), so the gradient the tracker
# follows matches the loss's median slope over fine steps only to within 6 % (the test's docstring), against 5 % with
# `off`. The renderer's own CB-KNN gradients are checked against float64 finite differences in test_cbknn.
MODES = {"off": (lambda: config(), 0.1), "paper": (lambda: with_cbknn_mode(config(), "paper"), 0.15)}


@jax.jit
def frozen_loss(problem: TrackingProblem, config, direction, offsets, centre):
    """The tracking loss at ``direction * offset`` for each offset [S], with the tracking mask frozen at ``direction *
    centre`` (one program per mode, every axis)."""
    objective = tracking_objective(problem, config)
    cfg = config.tracking
    mask = tracking_mask(objective.view_at(direction * centre), problem.depth, cfg.sil_threshold)

    def one(offset):  # SplaTAM's summed L1 terms, written out again
        view = objective.view_at(direction * offset)
        rendered = rendered_depth(view, cfg.normalized_depth)
        return (cfg.lambda_depth * jnp.sum(jnp.where(mask, jnp.abs(rendered - problem.depth), 0.0))
                + objective.lambda_color * jnp.sum(jnp.where(mask[..., None], jnp.abs(view.color - problem.color),
                                                             0.0)))

    return jax.lax.map(one, offsets)  # the render once in the program: a vmapped one compiled 2x longer


@pytest.mark.parametrize("mode", list(MODES))
# tz and rz (8-9 s each per mode) in the slow suite: a translation and a rotation axis stay in the default one.
@pytest.mark.parametrize("axis", ["tx", pytest.param("tz", marks=pytest.mark.slow), "rx",
                                  pytest.param("rz", marks=pytest.mark.slow)])
def test_landscape_gradients_agree_with_finite_differences_of_its_loss(mode, axis):
    """The gradient holds the tracking mask fixed (``stop_gradient``), and CB-KNN's neighbour selection is discrete,
    so the loss has small jumps where a pixel enters the mask or a neighbour set changes (in ``paper`` mode, local
    slopes measured between 0.005 cm steps range from -9 to 27 around a smooth slope of 4). The finite difference
    is therefore taken of the loss with the mask frozen at the evaluation point, as the median slope over 160 steps
    of 0.00125 units (the median skips the jumps; over 40 steps of 0.005 most steps held a jump, and on an AMD EPYC,
    whose map differs in its last bits, the median there was 1.39 against a gradient of 2.29 at tx 0.35 in ``paper``
    mode; over 160 it is 2.16, and every case of both modes and all four axes there is within 6 %)."""
    gaussians, color, depth, w2c = _map_and_frame()
    make_config, tolerance = MODES[mode]
    mode_config = make_config()
    direction = pure.directions((axis,))[0]
    at = jnp.asarray([-0.6, 0.35, 0.8], jnp.float32)  # cm or deg, away from the L1 kink at 0
    smooth, gamma = jnp.bool_(mode != "off"), jnp.float32(0.3)
    intrinsics = tiny_sequence().intrinsics
    problem = TrackingProblem(gaussians, color, depth, w2c, intrinsics, smooth, gamma)
    _, grad = jax.jit(pure.loss_and_grad)(problem, mode_config, direction, at)
    step = 0.00125
    for centre, g in zip(at, np.asarray(grad)):
        offsets = centre + step * jnp.arange(-80, 81, dtype=jnp.float32)
        values = np.asarray(frozen_loss(problem, mode_config, direction, offsets, centre), np.float64)
        fd = float(np.median(np.diff(values) / np.diff(np.asarray(offsets, np.float64))))
        assert abs(g - fd) <= tolerance * abs(fd) + 0.3, (float(centre), g, fd)
        assert abs(fd) > 1.0  # a real slope, not a flat loss


def test_basin_width_is_the_largest_radius_converged_on_both_sides():
    offsets = [-2, -1, 0, 1, 2]
    assert pure.basin_width(offsets, [True] * 5) == 2
    assert pure.basin_width(offsets, [False, True, True, True, True]) == 1
    assert pure.basin_width(offsets, [True, True, False, True, True]) == 0
    assert pure.basin_width([-1.5, -0.5, 0.5, 1.5], [True, True, True, False]) == 0.5


@pytest.mark.parametrize("argv, message", [
    (["--frame", "0"], "--frame must be >= 1"),
    (["--frame", "3", "--axes", "tx,qq"], "--axes must name"),
    (["--frame", "3", "--steps", "1"], "--steps must be >= 2"),
    (["--frame", "99", "--max-frames", str(FRAMES)], "past the sequence's last frame"),
    (["--frame", "3", "--axes", "tx", "--grid2d"], "--grid2d needs --axes naming exactly two axes, got tx"),
    (["--frame", "3", "--axes", "tx,ry,rz", "--grid2d"], "--grid2d needs --axes naming exactly two axes"),
    (["--frame", "3", "--modes", "off,blurry"], "--modes must name distinct modes among off, paper"),
    (["--frame", "3", "--modes", "paper,paper"], "--modes must name distinct modes"),
    (["--frame", "3", "--batch", "0"], "--batch must be >= 1"),
])
def test_bad_landscape_arguments_are_one_line_errors(tmp_path, capsys, argv, message):
    assert main(["landscape", "--out", str(tmp_path / "l"), *RUN, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_without_ground_truth_the_reference_is_the_pose_slam_gives_frame_t(tmp_path):
    """On a recording without ground truth the reference (written into landscape.json) is frame T's pose as SLAM's
    step tracks it on the same map of frames 0..T-1: the landscape poses the tracker's own problem."""
    data = write_tum(tiny_sequence(), tmp_path / "room")
    (data / "groundtruth.txt").unlink()
    out = tmp_path / "l"
    # One mode: the reference does not depend on the modes (whose landscapes the other tests check).
    # The axes and grid of the module's landscape (its compiled `off` program), without --map-from gt.
    landscape = [arg for arg in LANDSCAPE if arg not in ("--map-from", "gt")]
    assert main(["landscape", "--out", str(out), "--dataset", "tum", "--path", str(data), "--chunk", str(CHUNK),
                 *OVERRIDES, *landscape, "--modes", "off"]) == 0
    doc = json.loads((out / "landscape.json").read_text())
    assert doc["reference"] == "tracked"
    sequence = open_sequence("tum", data)
    frames = [sequence.read_host(i) for i in range(FRAME + 1)]
    # The map as the CLI built it, through the program it exported (the direct call gives the same bits: see
    # test_programs).
    state = slam_run(frames[:FRAME], config(), sequence.intrinsics, chunk=CHUNK, call=exported_call()).state
    # SLAM's step on frame T: the scan of the same program over a chunk whose other frames are padding.
    chunk = to_device(stack_frames([frames[FRAME]] * CHUNK))
    valid = jnp.arange(CHUNK) == 0
    _, outputs = exported_call()(run_chunk, state, chunk, valid, config(), sequence.intrinsics,
                                 unknown_poses(CHUNK))
    assert not bool(outputs.retried[0])
    np.testing.assert_allclose(np.asarray(doc["reference_w2c"]), np.asarray(outputs.w2c[0]), atol=2e-6)
