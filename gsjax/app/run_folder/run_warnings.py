"""What a run words as warnings: frames without usable depth, tracking that diverged, depth in an implausible unit.

One function of the per-frame outputs and the sequence (:func:`run_warnings`), so ``gsjax run`` (resumed or not),
its live progress and ``gsjax sweep`` list the same warnings in ``metrics.json``. The core decides which frames had
usable depth or diverged; the host only words it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gsjax.data.sequence import Sequence
from gsjax.frame import Frame
from gsjax.slam.config import SlamConfig
from gsjax.slam.system import StepOutputs

# Median depth (m) of a frame outside this range means the depth scale is almost surely wrong for an indoor scene.
PLAUSIBLE_MEDIAN_DEPTH_M = (0.1, 20.0)


def run_warnings(sequence: Sequence, config: SlamConfig, outputs: StepOutputs, read: Callable[[int], Frame], *,
                 start: int = 0, depth_units: bool = True) -> list[str]:
    """The warnings of frames ``start`` .. ``start + T - 1``, in frame order.

    Args:
      outputs: the frames' :class:`gsjax.slam.system.StepOutputs` on the host, each field [T, ...].
      read: frame ``t``'s host frame (only the first processed frame is read, for its depth unit).
      depth_units: check the depth unit at the first frame that was processed (a run checks it once).
    """
    skipped = np.asarray(outputs.skipped, bool)
    retried = np.asarray(outputs.retried, bool)
    diverged = np.asarray(outputs.diverged, bool)
    started = np.asarray(outputs.num_gaussians) > 0
    depth_valid = np.asarray(outputs.depth_valid, np.float64)
    processed = np.flatnonzero(~skipped)
    first = int(processed[0]) if depth_units and processed.size else -1
    messages = []
    for i in range(len(skipped)):
        t = start + i
        if i == first and (message := depth_unit_warning(sequence, t, read(t))):
            messages.append(message)
        if skipped[i]:
            messages.append(skipped_warning(sequence, t, float(depth_valid[i]), config, bool(started[i])))
        if retried[i]:
            messages.append(divergence_warning(sequence, t, bool(diverged[i])))
    return messages


def depth_unit_warning(sequence: Sequence, index: int, frame: Frame) -> str | None:
    """A warning when frame ``index``'s median valid depth is implausible for an indoor RGB-D camera."""
    depth = np.asarray(frame.depth)
    median = float(np.median(depth[depth > 0]))
    low, high = PLAUSIBLE_MEDIAN_DEPTH_M
    if low <= median <= high:
        return None
    scale = f"{sequence.depth_scale:g} raw units per metre" if sequence.depth_scale else "the dataset's scale"
    return (f"{sequence.describe_frame(index)}: median depth {median:.3g} m is outside {low:g}-{high:g} m; the depth "
            f"scale ({scale}) looks wrong for this recording: give the right one with --depth-scale S")


def skipped_warning(sequence: Sequence, index: int, depth_valid: float, config: SlamConfig, started: bool) -> str:
    """Frame ``index`` was not tracked or mapped: ``depth_valid`` (its fraction of pixels with depth) is below
    ``config.min_valid_depth``; ``started``: whether the map existed by then."""
    then = "" if started else "; the map starts at the first frame with depth"
    return (f"{sequence.describe_frame(index)}: only {100 * depth_valid:.1f}% of the pixels have valid depth (below "
            f"min_valid_depth {100 * float(config.min_valid_depth):g}%); the frame is not tracked or mapped, its pose "
            f"is the constant-velocity prediction{then}")


def divergence_warning(sequence: Sequence, index: int, diverged: bool) -> str:
    """Frame ``index``'s tracking was retried (``diverged``: and the retry diverged too)."""
    if diverged:
        return (f"{sequence.describe_frame(index)}: tracking diverged twice (beyond tracking.guard.max_step_m / "
                "max_step_deg of the constant-velocity prediction); the frame keeps the prediction")
    return (f"{sequence.describe_frame(index)}: tracking diverged (a loss jump or a pose beyond the step bound); "
            "retried once with smaller steps")
