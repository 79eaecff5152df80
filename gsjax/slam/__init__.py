"""The SLAM system, pure JAX: configs and presets, the state, and one step per frame scanned over chunks.

    from gsjax import slam
    config = slam.with_cbknn_mode(slam.preset("cpu"), "paper")
    state = slam.initial_state(capacity, height, width, keyframe_capacity, num_frames, seed=0)
    state, outputs = slam.run_chunk(state, frames, valid, config, intrinsics)
"""

from gsjax.slam.config import CBKNNConfig, DensifyConfig, MappingConfig, SlamConfig, TrackingConfig
from gsjax.slam.presets import preset, with_cbknn_mode
from gsjax.slam.state import KeyframeBuffer, SlamState, initial_state, keyframe_capacity_for
from gsjax.slam.system import StepOutputs, run_chunk, step

__all__ = [
    "CBKNNConfig",
    "DensifyConfig",
    "KeyframeBuffer",
    "MappingConfig",
    "SlamConfig",
    "SlamState",
    "StepOutputs",
    "TrackingConfig",
    "initial_state",
    "keyframe_capacity_for",
    "preset",
    "run_chunk",
    "step",
    "with_cbknn_mode",
]
