"""The names users type (dataset layouts, presets, CB-KNN modes), in one place; imports nothing, so the CLI can
offer them without loading JAX."""

DATASETS = ("tum", "replica", "scannet", "7scenes")  # layouts on disk gsjax.data.open_sequence reads
BAGS = ("rosbag", "realsense")  # recordings read from one file or bag folder (gsjax.data.rosbag, .realsense)
SYNTHETIC = "synthetic"  # gsjax.data.open_sequence's generated sequence (the ray-cast room)
PRESETS = ("cpu", "replica", "tum", "scannet")  # gsjax.slam.presets.preset
CBKNN_MODES = ("off", "code_parity", "paper")  # gsjax.slam.config.CBKNNConfig.mode
