"""SLAM config: presets build, dotted overrides with errors naming the field, dict round trip, traced vs static."""

from __future__ import annotations

import dataclasses
import json

import jax
import pytest

from gsjax.config.names import PRESETS
from gsjax.config.text import apply_overrides, config_from_dict, config_to_dict
from gsjax.slam.config import SlamConfig
from gsjax.slam.presets import preset, with_cbknn_mode


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_builds_a_valid_config_with_cbknn_off(name):
    config = preset(name)
    assert isinstance(config, SlamConfig)
    assert config.cbknn.mode == "off"  # presets are SplaTAM; the CB-KNN mode is chosen separately
    for mode in ("off", "code_parity", "paper"):
        assert with_cbknn_mode(config, mode).cbknn.mode == mode


def test_presets_hold_the_per_dataset_values_of_the_spec():
    # method_spec A.11 (iterations, window) and D.6 (K0 = 5 Replica, 8 TUM/ScanNet); scene radius ratio 3 / 2 / 3.
    expected = {"replica": (40, 60, 24, 5.0, 3.0), "tum": (200, 30, 20, 8.0, 2.0), "scannet": (100, 30, 10, 8.0, 3.0)}
    for name, (track_iters, map_iters, window, k0, ratio) in expected.items():
        c = preset(name)
        assert (c.tracking.iters, c.mapping.iters, c.mapping.window_size) == (track_iters, map_iters, window)
        assert (c.cbknn.params.k0, c.scene_radius_depth_ratio) == (k0, ratio)
        assert c.cbknn.lambda_color_keyframe == 0.6
        assert (c.cbknn.params.alpha, c.cbknn.params.beta) == (0.2, 0.3)


def test_unknown_preset_is_a_value_error_listing_the_presets():
    with pytest.raises(ValueError, match="unknown preset 'nope'.*replica"):
        preset("nope")


def test_overrides_set_nested_fields_by_dotted_name_and_parse_each_type():
    config = apply_overrides(
        preset("cpu"),
        {
            "tracking.iters": "7",  # int
            "tracking.optimizer": "lm",  # str
            "tracking.normalized_depth": "false",  # bool
            "mapping.lr_means": "2e-3",  # float
            "mapping.prune_iters": "0,5,10",  # tuple
            "cbknn.params.alpha": "0.35",  # two levels deep
            "cbknn.mode": "paper",
            "raster.near": "0.1",
        },
    )
    assert config.tracking.iters == 7 and config.tracking.optimizer == "lm"
    assert config.tracking.normalized_depth is False
    assert config.mapping.lr_means == 2e-3 and config.mapping.prune_iters == (0, 5, 10)
    assert config.cbknn.params.alpha == 0.35 and config.cbknn.mode == "paper"
    assert config.raster.near == 0.1
    # Everything else is untouched.
    assert config.mapping.iters == preset("cpu").mapping.iters
    assert config.cbknn.params.k0 == preset("cpu").cbknn.params.k0


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("tracking.nope", "1", r"--tracking\.nope: unknown field 'nope'"),
        ("nope", "1", r"--nope: unknown field 'nope'"),
        ("tracking.iters.deeper", "1", r"--tracking\.iters\.deeper: 'deeper' is not a config section"),
        ("tracking", "1", r"--tracking: cannot read '1' as TrackingConfig"),
        ("tracking.iters", "abc", r"--tracking\.iters: cannot read 'abc' as int"),
        ("tracking.iters", "2.5", r"--tracking\.iters: cannot read '2\.5' as int"),
        ("tracking.normalized_depth", "maybe", r"--tracking\.normalized_depth: cannot read 'maybe' as bool"),
        ("mapping.lr_rgb", "fast", r"--mapping\.lr_rgb: cannot read 'fast' as float"),
        ("tracking.iters", "0", r"--tracking\.iters: .*tracking\.iters must be an int >= 1"),
        ("tracking.optimizer", "sgd", r"--tracking\.optimizer: .*tracking\.optimizer must be one of"),
        ("tracking.lr_trans", "-1", r"--tracking\.lr_trans: .*tracking\.lr_trans must be a finite number"),
        ("tracking.lr_trans", "nan", r"--tracking\.lr_trans: .*tracking\.lr_trans must be a finite number"),
        ("tracking.sil_threshold", "1.5", r"--tracking\.sil_threshold: .*must be a finite number >= 0 and <= 1, "
                                          r"got 1\.5"),
        ("densify.init_opacity", "1", r"--densify\.init_opacity: .*init_opacity must be a finite number > 0 and < 1"),
        ("cbknn.mode", "always", r"--cbknn\.mode: .*cbknn\.mode must be one of"),
        ("cbknn.params.alpha", "-0.1", r"--cbknn\.params\.alpha: .*CBKNN\.alpha must be a finite number >= 0 \(px\)"),
        ("tracking.guard.max_step_m", "0", r"--tracking\.guard\.max_step_m: tracking\.guard\.max_step_m must be a "
                                           r"finite number > 0 \(m\), got 0\.0"),
        ("tracking.guard", "1", r"--tracking\.guard: cannot read '1' as DivergenceGuard \(a config section"),
        ("mapping.window_size", "1", r"--mapping\.window_size: .*mapping\.window_size must be an int >= 2"),
    ],
)
def test_overrides_reject_unknown_names_and_invalid_values_naming_the_field(name, value, message):
    with pytest.raises(ValueError, match=message):
        apply_overrides(preset("cpu"), {name: value})


def test_paper_mode_rejects_a_kernel_larger_than_the_contributor_slots():
    config = with_cbknn_mode(preset("cpu"), "paper")
    with pytest.raises(ValueError, match=r"--raster\.max_contributors: .*cbknn\.params\.k_max \(16\) exceeds"):
        apply_overrides(config, {"raster.max_contributors": "8"})
    # Outside paper mode renders are never smoothed, so the same setting is fine.
    assert apply_overrides(preset("cpu"), {"raster.max_contributors": "8"}).raster.max_contributors == 8


@pytest.mark.parametrize("name", PRESETS)
def test_config_dict_round_trips_through_json(name):
    config = apply_overrides(
        with_cbknn_mode(preset(name), "paper"),
        {"mapping.prune_iters": "3,4", "cbknn.params.select": "top_weight", "tracking.lr_rot": "1.25e-3"},
    )
    data = json.loads(json.dumps(config_to_dict(config)))
    assert config_from_dict(data) == config
    # Partial dicts fill in from the base.
    assert config_from_dict({"tracking": {"iters": 9}}, base=config) == dataclasses.replace(
        config, tracking=dataclasses.replace(config.tracking, iters=9)
    )


def test_config_from_dict_rejects_unknown_keys():
    with pytest.raises(ValueError, match="unknown field 'bogus'"):
        config_from_dict({"bogus": 1})
    with pytest.raises(ValueError, match="unknown field 'bogus'"):
        config_from_dict({"tracking": {"bogus": 1}})


def test_swept_hyperparameters_are_traced_leaves_and_shapes_modes_are_static():
    """Changing a learning rate, loss weight, CB-KNN alpha/k0/beta, an iteration count within its cap or CB-KNN's
    mode and switches within the program's caps keeps the treedef (no recompilation, vmap-able); changing a shape,
    the optimizer, a count past its cap, the mode to ``paper`` from a program without CB-KNN's correction or a noise
    level above 0 in a program without noise changes it."""
    base = preset("cpu")
    structure = jax.tree_util.tree_structure(base)
    traced = {"tracking.lr_trans": "0.01", "tracking.lambda_color": "0.3", "mapping.lr_rgb": "0.01",
              "densify.sil_threshold": "0.4", "cbknn.params.alpha": "0.5", "cbknn.params.k0": "3",
              "cbknn.params.beta": "0.1", "cbknn.lambda_color_keyframe": "0.7", "scene_radius_depth_ratio": "4",
              "mapping.clamp_rgb": "true", "tracking.blur.sigma_px": "1.5", "tracking.coarse.sigma_px": "2",
              "noise.persistent_frame": "5", "tracking.iters": "5",
              "tracking.strided_iters": "20", "tracking.reselect_every": "1", "tracking.stop.window": "3",
              "mapping.iters": "25", "mapping.every": "2", "mapping.reselect_every": "10", "cbknn.mode": "code_parity",
              "cbknn.track_keyframes": "false", "cbknn.map_keyframes": "false", "cbknn.densify": "false",
              "cbknn.kf_overlap_smoothing": "true"}
    for name, value in traced.items():
        assert jax.tree_util.tree_structure(apply_overrides(base, {name: value})) == structure, name
    # Every mode in a program compiled with the correction (a sweep's common caps): one treedef.
    smoothing = base.with_caps(dataclasses.replace(base.caps, smoothing=True))
    modes = {mode: apply_overrides(smoothing, {"cbknn.mode": mode}) for mode in ("off", "code_parity", "paper")}
    assert len({jax.tree_util.tree_structure(c) for c in modes.values()}) == 1
    assert jax.tree_util.tree_structure(apply_overrides(base, {"cbknn.mode": "paper"})) != structure
    # Noise levels likewise: any level in a program that draws noise; the first level above 0 compiles the draws in.
    noisy = base.with_caps(dataclasses.replace(base.caps, noise=True))
    for name in ("noise.persistent_means_cm", "noise.depth_cm", "noise.map_rgb"):
        assert jax.tree_util.tree_structure(apply_overrides(noisy, {name: "1"})) == jax.tree_util.tree_structure(noisy)
        assert jax.tree_util.tree_structure(apply_overrides(base, {name: "1"})) != structure, name
    static = {"tracking.iters": "33", "tracking.optimizer": "lm", "mapping.window_size": "4",
              "cbknn.params.k_max": "8", "keyframe_every": "3", "raster.max_contributors": "32",
              "tracking.blur.radius_px": "4", "mapping.reselect_every": "1", "mapping.strided_iters": "10"}
    for name, value in static.items():
        assert jax.tree_util.tree_structure(apply_overrides(base, {name: value})) != structure, name


def test_a_preset_owns_its_resolution_and_scales_its_pixel_settings():
    from gsjax.slam.presets import PRESET_WIDTH, working_downscale

    cpu = preset("cpu")
    assert preset("cpu", PRESET_WIDTH["cpu"]) is not None and preset("cpu", 80) == cpu  # its own width: unchanged
    full = preset("cpu", 640)  # `gsjax run --preset cpu --downscale 1` on 640x480 input
    assert full.mapping.overlap_margin == 8 * cpu.mapping.overlap_margin == 20.0  # SplaTAM's 20 px at 640
    assert full.cbknn.params.alpha == pytest.approx(8 * cpu.cbknn.params.alpha)
    assert full.tracking.coarse.sigma_px == 8 * cpu.tracking.coarse.sigma_px  # the smoothing is in pixels too
    unscaled = dataclasses.replace(full.tracking, coarse=cpu.tracking.coarse)
    assert config_to_dict(unscaled) == config_to_dict(cpu.tracking)  # nothing else is in pixels
    fraction = dataclasses.replace(cpu, cbknn=dataclasses.replace(
        cpu.cbknn, params=dataclasses.replace(cpu.cbknn.params, shift_mode="fraction")))
    from gsjax.slam.presets import at_width

    assert at_width(fraction, 640, 80).cbknn.params.alpha == cpu.cbknn.params.alpha  # a fraction, not px
    assert preset("tum", 320).mapping.overlap_margin == preset("tum").mapping.overlap_margin / 2
    # The size bound of pruning follows the pixel footprint: twice the bound at half the width, the same at the
    # preset's own width (the paper presets at their datasets' resolution are SplaTAM's, untouched).
    assert preset("cpu", 40).mapping.prune_scale_ratio == 2 * cpu.mapping.prune_scale_ratio
    assert full.mapping.prune_scale_ratio == cpu.mapping.prune_scale_ratio / 8
    for name, width in PRESET_WIDTH.items():
        assert preset(name, width).mapping == preset(name).mapping
    assert preset("replica").mapping.prune_scale_ratio == 0.1  # SplaTAM's value
    assert [working_downscale("cpu", w) for w in (80, 160, 640, 1200)] == [1, 2, 8, 15]
    assert working_downscale("replica", 1200) == working_downscale("tum", 640) == 1  # paper presets: native
    with pytest.raises(ValueError, match="unknown preset 'fast'"):
        preset("fast")
