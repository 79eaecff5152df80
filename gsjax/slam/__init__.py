"""The SLAM system, pure JAX: configs and presets, the state, and one step per frame scanned over chunks.

    from gsjax import slam
    config = slam.with_cbknn_mode(slam.preset("cpu"), "paper")
    result = slam.run(frames, config, intrinsics, seed=0)        # in memory: poses, per-frame outputs, state
    state = slam.initial_state(capacity, height, width, keyframe_capacity, num_frames, seed=0)
    state, outputs = slam.run_chunk(state, frames, valid, config, intrinsics)   # one jitted scan over a chunk
"""

from gsjax.slam.config import CBKNNConfig, DensifyConfig, MappingConfig, NoiseConfig, SlamConfig, TrackingConfig
from gsjax.slam.driver import RunResult, run
from gsjax.slam.presets import preset, with_cbknn_mode
from gsjax.slam.state import KeyframeBuffer, SlamState, initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs, run_chunk, step

__all__ = [
    "CBKNNConfig",
    "DensifyConfig",
    "KeyframeBuffer",
    "MappingConfig",
    "NoiseConfig",
    "RunResult",
    "SlamConfig",
    "SlamState",
    "StepOutputs",
    "TrackingConfig",
    "initial_state",
    "keyframe_capacity_for",
    "preset",
    "run",
    "run_chunk",
    "step",
    "with_cbknn_mode",
]
