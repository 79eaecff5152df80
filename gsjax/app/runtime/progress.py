"""The progress bar of the long-running commands (``run``, ``sweep``, ``landscape``)."""

from __future__ import annotations


class Progress:
    """A tqdm bar over frames (or nothing), updated once per chunk; ``write`` prints above it."""

    def __init__(self, total: int, initial: int, enabled: bool):
        self._bar = None
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=initial, unit="frame", dynamic_ncols=True)

    def update(self, frames: int, **fields) -> None:
        if self._bar is not None:
            self._bar.set_postfix(fields, refresh=False)
            self._bar.update(frames)

    def write(self, message: str, file=None) -> None:
        if self._bar is not None:
            self._bar.write(message, file=file)
        else:
            print(message, file=file, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
