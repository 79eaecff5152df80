"""Checkpoints of a SLAM run (orbax): the state pytree plus a JSON record, written atomically, resumable.

Each checkpoint is a numbered step directory under ``<out>/checkpoints`` holding ``state`` (the
:class:`gsjax.slam.state.SlamState` arrays) and ``meta`` (JSON: frames done, capacity, per-frame outputs so far,
config). Orbax writes into a temporary directory and renames it when complete, so an interrupted save never
leaves a half-written checkpoint behind; the last two are kept.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import orbax.checkpoint as ocp


class Checkpoints:
    """A checkpoint directory: ``save(step, state, meta)``, ``latest()``, ``restore(step, like_state)``."""

    def __init__(self, directory: str | os.PathLike, keep: int = 2):
        self.directory = Path(directory).resolve()
        self._manager = ocp.CheckpointManager(
            self.directory, options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
        )

    def save(self, step: int, state, meta: dict) -> None:
        """Write checkpoint ``step`` (blocking until it is complete on disk)."""
        self._manager.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state),
                                                         meta=ocp.args.JsonSave(meta)), force=True)
        self._manager.wait_until_finished()

    def latest(self) -> int | None:
        """The newest complete checkpoint's step, or None."""
        return self._manager.latest_step()

    def read_meta(self, step: int) -> dict:
        return self._manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta

    def restore(self, step: int, like_state):
        """(state, meta) of checkpoint ``step``; ``like_state`` gives the pytree structure, shapes and dtypes."""
        abstract = jax.tree_util.tree_map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), like_state)
        restored = self._manager.restore(
            step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore())
        )
        return restored.state, restored.meta

    def close(self) -> None:
        self._manager.close()
