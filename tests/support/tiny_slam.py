"""Shared tiny setup of the SLAM tests: a 40x30 synthetic room, a tiny config, and tree comparisons.

Compilation dominates on CPU (about 12 s per distinct SLAM scan program), so every test that runs the scan uses
the same static config (:func:`tiny_config`, per CB-KNN mode) and the same shapes (``FRAMES`` frames, chunks of
``CHUNK``, capacity ``CAPACITY`` = the runner's default 2 H W, keyframe capacity of a ``FRAMES``-frame run). The
runner and CLI tests are given options that build the very same program, so within one pytest process each
program compiles once.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from gsjax.app.session.runner import RunOptions
from gsjax.config.fields import kind_of, settings_fields, spec_of
from gsjax.data.sequence import Sequence
from gsjax.data.synthetic import SyntheticConfig, synthetic_sequence
from gsjax.frame import Frame, stack_frames, to_device
from gsjax.slam.config import SlamConfig
from gsjax.slam.loops import LoopCaps
from gsjax.slam.presets import preset, with_cbknn_mode
from gsjax.slam.state import SlamState, initial_state, keyframe_capacity_for

WIDTH, HEIGHT = 40, 30  # = the default synthetic 160x120 with `gsjax run --downscale 4`
FRAMES = 6
CHUNK = 3
CAPACITY = 2 * WIDTH * HEIGHT  # the runner's default capacity
# Tiny iteration counts: the scans over iterations compile to the same program whatever the count. No strided
# iterations (their renders would add to every tiny program's compile time; test_slam_tracking and test_slam_map
# test them).
TINY_COUNTS = {"tracking.iters": 3, "tracking.strided_iters": 0, "mapping.iters": 2, "mapping.strided_iters": 0}
TINY_OVERRIDES = {name: str(value) for name, value in TINY_COUNTS.items()}  # the same, as command-line text


# `gsjax run` / `gsjax sweep` flags for the tiny run (after --out): the synthetic room at 40x30, FRAMES frames.
TINY_RUN = ["--dataset", "synthetic", "--downscale", "4", "--max-frames", str(FRAMES), "--chunk", str(CHUNK),
            "--no-progress"] + [token for name, value in TINY_OVERRIDES.items() for token in (f"--{name}", value)]


_Config = TypeVar("_Config")
_KINDS = {"int": int, "float": float, "bool": bool, "str": str, "tuple": tuple}


def replaced(config: _Config, changes: Mapping[str, Any]) -> _Config:
    """``config`` with fields set by dotted name, e.g. ``{"tracking.iters": 3, "cbknn.params.alpha": 0.3}``:
    ``dataclasses.replace`` section by section, in order (as the command line's overrides set them, from typed values
    instead of text). Each value must have its field's declared type (an int field an int, a float field a float),
    the type the command line's codec gives it, so that the config is equal to the one the command line builds and
    compiles to the same program.

    Raises:
      AttributeError: naming the path, for an unknown field (or a derived one, such as ``caps``).
      TypeError: naming the path, for a value of another type, or for a section given as a value.
    """
    for path, value in changes.items():
        config = _replaced_at(config, path.split("."), value, path)
    return config


def _replaced_at(obj, names: list[str], value, path: str):
    fields = {f.name: f for f in settings_fields(obj)} if dataclasses.is_dataclass(obj) else {}
    if names[0] not in fields:
        raise AttributeError(f"{path}: {type(obj).__name__} has no field {names[0]!r} (fields: {sorted(fields)})")
    field = fields[names[0]]
    if len(names) > 1:
        value = _replaced_at(getattr(obj, names[0]), names[1:], value, path)
    elif spec_of(field) is None:
        raise TypeError(f"{path}: is a config section (set its fields, {path}.NAME)")
    else:
        kind = kind_of(field)
        expected = _KINDS.get(kind.split(" |")[0])
        if not (type(value) is expected or (value is None and "None" in kind) or expected is None):
            raise TypeError(f"{path}: {kind} field, got {value!r} ({type(value).__name__})")
    return dataclasses.replace(obj, **{names[0]: value})


def run_options(out, **changes) -> RunOptions:
    """The runner's options for a tiny run into ``out``: a chunk and a checkpoint every CHUNK frames, no progress."""
    return RunOptions(out=out, **{"chunk": CHUNK, "checkpoint_every": CHUNK, "progress": False, **changes})


@functools.lru_cache(maxsize=None)
def tiny_sequence(num_frames: int = FRAMES) -> Sequence:
    """The synthetic room at 40x30 (exact depth, every pixel valid, GT poses)."""
    return synthetic_sequence(SyntheticConfig(width=WIDTH, height=HEIGHT, num_frames=num_frames))


def tiny_config(mode: str = "off") -> SlamConfig:
    """The ``cpu`` preset at the tiny width with CB-KNN ``mode`` and tiny iteration counts (:data:`TINY_COUNTS`):
    the config ``gsjax run --preset cpu --cbknn MODE`` with :data:`TINY_OVERRIDES` builds for 40x30 frames (so the
    CLI tests reuse the compiled scan and record this very config; test_driver checks that they are equal)."""
    return replaced(with_cbknn_mode(preset("cpu", WIDTH), mode), TINY_COUNTS)


def frames(begin: int, end: int, num_frames: int = FRAMES) -> Frame:
    """Frames [begin, end) of :func:`tiny_sequence`, stacked along a leading axis, on device."""
    sequence = tiny_sequence(num_frames)
    return to_device(stack_frames([sequence.read_host(i) for i in range(begin, end)]))


def initial(seed: int = 0) -> SlamState:
    """The state the runner starts a ``FRAMES``-frame run from (default capacity)."""
    config = tiny_config()
    return initial_state(CAPACITY, HEIGHT, WIDTH, keyframe_capacity_for(FRAMES, config.keyframe_every), FRAMES, seed)


def relative_gt_w2c(num_frames: int = FRAMES) -> np.ndarray:
    """[T, 4, 4] ground-truth world-to-camera poses in the SLAM world frame (the first camera), float64."""
    _, c2w, _ = tiny_sequence(num_frames).gt_trajectory()
    return np.linalg.inv(np.linalg.inv(c2w[0]) @ c2w)


def _leaves(tree):
    return jax.tree_util.tree_leaves_with_path(tree)


def assert_trees_equal(actual, expected) -> None:
    """Same structure and every leaf bit for bit equal (NaNs equal)."""
    assert jax.tree_util.tree_structure(actual) == jax.tree_util.tree_structure(expected)
    for (path, a), b in zip(_leaves(actual), jax.tree_util.tree_leaves(expected)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))


def assert_trees_close(actual, expected, rtol: float, atol: float, few: int = 0, few_atol: float = 0.0) -> None:
    """Same structure; integer and bool leaves equal, floating leaves within ``rtol``/``atol``, except at most
    ``few`` entries of each, which may differ by up to ``few_atol``."""
    assert jax.tree_util.tree_structure(actual) == jax.tree_util.tree_structure(expected)
    for (path, a), b in zip(_leaves(actual), jax.tree_util.tree_leaves(expected)):
        a, b = np.asarray(a), np.asarray(b)
        name = jax.tree_util.keystr(path)
        if np.issubdtype(a.dtype, np.floating):
            outside = ~np.isclose(a, b, rtol=rtol, atol=atol, equal_nan=True)
            if 0 < outside.sum() <= few:
                np.testing.assert_allclose(a[outside], b[outside], rtol=0, atol=few_atol, err_msg=name)
            else:
                np.testing.assert_allclose(a, b, rtol=rtol, atol=atol, err_msg=name)
        else:
            np.testing.assert_array_equal(a, b, err_msg=name)


def trees_differ(a, b) -> bool:
    """Whether any floating leaf differs (to show that a comparison is not vacuous)."""
    return any(
        not np.array_equal(np.asarray(x), np.asarray(y))
        for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
    )


def all_finite(tree) -> bool:
    return all(
        bool(jnp.all(jnp.isfinite(x)))
        for x in jax.tree_util.tree_leaves(tree)
        if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)
    )


# ------------------------------------------------------------------------------ a one-frame map, and its mapping

MAP_VIEWS = (0, 2)  # frames in the mapping window of the map fixtures (GT poses)


# The loop caps of the map and tracker tests' programs: any of their iteration counts (strided or not, contributors
# chosen once or every iteration) runs one program per optimizer.
MAP_CAPS = LoopCaps(tracking=64, tracking_strided=64, mapping=32, mapping_strided=32, mapping_reselect=True)


def map_config() -> SlamConfig:
    """The ``cpu`` preset (normalised-depth tracking) with 30 mapping iterations, every iteration on every pixel,
    compiled for :data:`MAP_CAPS`."""
    return replaced(preset("cpu"), {"mapping.iters": 30, "mapping.strided_iters": 0,
                                    "tracking.strided_iters": 0}).with_caps(MAP_CAPS)


def first_frame_map():
    """SplaTAM's initialisation from frame 0 (one Gaussian per pixel, world = first camera), H W slots."""
    from gsjax.gaussians import gaussians_from_rgbd

    frame = tiny_sequence()[0]
    return gaussians_from_rgbd(frame.color, frame.depth, tiny_sequence().intrinsics, jnp.eye(4, dtype=jnp.float32))


def window_frames(frame_ids=MAP_VIEWS):
    """:class:`gsjax.slam.mapping.WindowFrames` of the given frames at their GT poses (all keyframes, all valid)."""
    from gsjax.slam.mapping import WindowFrames

    chunk = frames(0, FRAMES)
    ids = np.asarray(frame_ids)
    count = len(ids)
    return WindowFrames(color=chunk.color[ids], depth=chunk.depth[ids],
                 w2c=jnp.asarray(relative_gt_w2c()[ids], jnp.float32), gamma=jnp.zeros(count, jnp.float32),
                 keyframe=jnp.ones(count, bool), valid=jnp.ones(count, bool))


def scene_radius(config: SlamConfig):
    return jnp.max(tiny_sequence()[0].depth) / config.scene_radius_depth_ratio


@functools.lru_cache(maxsize=None)
def _map_window_jit():
    from gsjax.slam.mapping import map_window

    return jax.jit(map_window)


def run_map_window(gaussians, seed: int = 0, config: SlamConfig | None = None, first_map=False):
    """``map_window`` over :func:`window_frames` with :func:`map_config` (one compiled program for all callers that
    keep the config's static fields)."""
    config = map_config() if config is None else config
    return _map_window_jit()(jax.random.PRNGKey(seed), gaussians, window_frames(), tiny_sequence().intrinsics, config,
                             scene_radius(config), jnp.asarray(first_map))



# ------------------------------------------------------------------------------ the one SLAM program of the suite


def scan(stacked: Frame, config: SlamConfig | None = None, state: SlamState | None = None, valid=None,
         cuts: tuple[int, ...] | None = None) -> tuple[SlamState, object]:
    """``run_chunk`` over ``stacked`` frames (any number) in chunks of CHUNK, each through the program ``gsjax run``
    exports for the tiny config (so the whole suite compiles it once; exported and direct calls give the same bits,
    test_programs).

    Args:
      stacked: a stacked Frame of T frames.
      config: the config (:func:`tiny_config` by default).
      state: the state to start from (:func:`initial` by default).
      valid: [T] bool, the real frames (default all); False frames are padding.
      cuts: where chunks end (frame indices, increasing); default every CHUNK frames. A chunk of fewer frames is
        padded to CHUNK with copies of its last frame, marked invalid, as the runner pads the last chunk.

    Returns:
      (the state after the frames, their StepOutputs [T, ...]).
    """
    from gsjax.app.runtime.cache import exported_call
    from gsjax.slam.system import run_chunk, unknown_poses

    count = int(stacked.depth.shape[0])
    valid = jnp.ones(count, bool) if valid is None else jnp.asarray(valid, bool)
    bounds = [0, *(cuts if cuts is not None else range(CHUNK, count, CHUNK)), count]
    state = initial() if state is None else state
    config = tiny_config() if config is None else config
    parts = []
    for begin, end in zip(bounds[:-1], bounds[1:]):
        assert 0 < end - begin <= CHUNK, (begin, end)
        index = jnp.minimum(jnp.arange(begin, begin + CHUNK), end - 1)
        chunk = jax.tree_util.tree_map(lambda x, index=index: x[index], stacked)
        real = valid[index] & (jnp.arange(CHUNK) < end - begin)
        state, out = exported_call()(run_chunk, state, chunk, real, config, tiny_sequence().intrinsics,
                                     unknown_poses(CHUNK))  # as the runner calls it: the same program
        parts.append(jax.tree_util.tree_map(lambda x, n=end - begin: x[:n], out))
    return state, jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *parts)
