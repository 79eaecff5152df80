"""``config.json`` as one typed record: what a run was given (:class:`RunInput`).

``gsjax run`` and ``gsjax sweep`` write it before the first frame; resume compares its :meth:`RunInput.resume_key`
with the checkpoint's, and the report and the viewer read it back with :func:`read_run_input`. The file's layout is
the run folder's ``format``, the command's account of its input (``describe``: dataset, path, preset, ...) as
top-level keys, then the run's size, chunk, seed, camera and config, then (a sweep's run) ``sweep``. Runs made before
a key existed read back with None; a run folder of another format is not resumed (:func:`older_run_message`).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

# What a resume must match, in the file's order.
RESUME_KEYS = ("frames", "width", "height", "chunk", "seed", "camera", "config")
# The layout of the run folders this gsjax writes (config.json, the checkpoints): 1 is gsjax before issue 48, whose
# files had no "format"; a resume refuses any other (gsjax has had no release: no older layout is converted).
RUN_FORMAT = 2


@dataclasses.dataclass(frozen=True, kw_only=True)
class RunInput:
    """What ``config.json`` holds.

    Attributes:
      describe: the command's account of its input (``dataset``, ``path``, ``preset``, ``cbknn``, ``downscale``,
        ``stride``, ``overrides``, ``intrinsics``, ``depth_scale``, ``sequence``, or what a caller recorded).
      frames: frames run; width, height: the working resolution (px); chunk: frames per compiled scan call; seed.
      camera: the intrinsics at the working resolution (``fx``, ``fy``, ``cx``, ``cy`` px; ``width``, ``height``
        px) and ``depth_scale`` (the depth files' raw units per metre).
      config: the :class:`gsjax.slam.config.SlamConfig` as a nested dict (:func:`gsjax.config.text.config_to_dict`).
      sweep: a sweep's run: its grid ``values``, ``batch`` and ``batch_size``.
      format: the run folder's layout (:data:`RUN_FORMAT`; None: a folder of gsjax before it was recorded).
    """

    describe: dict[str, Any] = dataclasses.field(default_factory=dict)
    frames: int | None = None
    width: int | None = None
    height: int | None = None
    chunk: int | None = None
    seed: int | None = None
    camera: dict[str, Any] | None = None
    config: dict[str, Any] | None = None
    sweep: dict[str, Any] | None = None
    format: int | None = RUN_FORMAT

    def to_json(self) -> dict[str, Any]:
        """The JSON object ``config.json`` holds."""
        value = {"format": self.format, **self.describe}
        value.update((key, getattr(self, key)) for key in RESUME_KEYS)
        if self.sweep is not None:
            value["sweep"] = self.sweep
        return value

    @classmethod
    def from_json(cls, value: Any) -> RunInput:
        """The record of a ``config.json`` object; raises ValueError when it is not a JSON object."""
        if not isinstance(value, dict):
            raise ValueError(f"expected a JSON object, got {type(value).__name__}")
        described = {k: v for k, v in value.items() if k not in (*RESUME_KEYS, "sweep", "format")}
        return cls(describe=described, sweep=value.get("sweep"), format=value.get("format"),
                   **{k: value[k] for k in RESUME_KEYS if k in value})

    def resume_key(self) -> dict[str, Any]:
        """What a resumed run must match: the size, chunk, seed, camera and config."""
        return {key: getattr(self, key) for key in RESUME_KEYS}


def older_run_message(where: str | Path, found: int | None) -> str:
    """What a resume says of a run folder of another layout than :data:`RUN_FORMAT` (``found``; None: written before
    the layout was recorded), and what to do."""
    return (f"{where} was written by another gsjax (run folder format {found or 1}; this gsjax writes and resumes "
            f"format {RUN_FORMAT}): run it again with --overwrite, or into a new --out")


def read_run_input(path: str | Path) -> RunInput:
    """Read a ``config.json``; raises ValueError naming the file when it cannot be read or is not one."""
    path = Path(path)
    try:
        return RunInput.from_json(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, ValueError) as error:
        raise ValueError(f"{path}: cannot be read as a run's config.json ({error})") from None
