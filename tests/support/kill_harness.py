"""Run ``gsjax`` with named events traced, and kill the process with SIGKILL at one of them.

    python tests/kill_harness.py TRACE KILL_AT -- run --out DIR ...

Events (one line each in TRACE, appended as they happen):

* ``write:<dir>/<name>``: an atomic write of a file (every output and checkpoint file goes through
  ``gsjax.io.atomic.atomic_write_bytes``). Killed there, the process first writes half the data into the writer's
  temporary file: the kill lands in the middle of the write.
* ``commit:<step>``: orbax about to rename a finished checkpoint step from its temporary directory.
* ``scan:<frame>``: a scan chunk starting at that frame is about to run.

``KILL_AT`` is an event name, or ``-`` for none; the first occurrence in this process is the one killed.
"""

from __future__ import annotations

import os
import secrets
import signal
import sys
from pathlib import Path

KILL_EXIT = -signal.SIGKILL  # the return code a subprocess killed this way reports


def main(trace: str, kill_at: str, argv: list[str]) -> int:
    from orbax.checkpoint._src.path import async_path

    import gsjax.app.cli
    import gsjax.app.run_folder.checkpoints
    import gsjax.app.run_folder.outputs
    import gsjax.app.session.loop as session
    import gsjax.app.session.runner
    import gsjax.io.atomic as atomic

    log = open(trace, "a", buffering=1)

    def event(name: str, before_kill=None) -> None:
        log.write(name + "\n")
        if name == kill_at:
            if before_kill is not None:
                before_kill()
            log.close()
            os.kill(os.getpid(), signal.SIGKILL)

    original_write = atomic.atomic_write_bytes

    def traced_write(path, data):
        path = Path(path)

        def half_written():
            tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
            with open(tmp, "wb") as f:
                f.write(data[: len(data) // 2])
                f.flush()
                os.fsync(f.fileno())

        event(f"write:{path.parent.name}/{path.name}", half_written)
        return original_write(path, data)

    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith("gsjax") and \
                getattr(module, "atomic_write_bytes", None) is original_write:
            module.atomic_write_bytes = traced_write

    original_rename = async_path.rename

    async def traced_rename(src, dst):
        event(f"commit:{Path(str(dst)).name}")
        return await original_rename(src, dst)

    async_path.rename = traced_rename

    original_pad = session.pad_chunk

    def traced_pad(frames, size):
        event(f"scan:{int(frames[0].index)}")
        return original_pad(frames, size)

    session.pad_chunk = traced_pad
    return gsjax.app.cli.main(argv)


if __name__ == "__main__":
    split = sys.argv.index("--")
    trace, kill_at = sys.argv[1:split]
    sys.exit(main(trace, kill_at, sys.argv[split + 1:]))
