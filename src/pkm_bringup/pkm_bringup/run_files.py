"""The space a run directory keeps for its end on a disk that may fill up (pure, no
rclpy). A full disk during a run left run.json empty, pkm-run in a traceback, and the
nodes' summaries empty. ``DiskReserve`` sets space aside when the run starts
(allocated blocks) and gives it back when it is needed: one when the loop is over,
before the nodes stop, one before pkm-run writes run.json and the report (the
recorder's last chunk may take the first). The nodes allocate their own summaries'
blocks, and JSON is written whole or not at all: pkm_common.files.
"""

from __future__ import annotations

import os
from pathlib import Path

from pkm_common.files import disk_full

__all__ = ["RESERVE_BYTES", "DiskReserve"]

RESERVE_BYTES = 1024 * 1024          # each of the two: the nodes' summaries; run.json (~50 kB) and the report


class DiskReserve:
    """``size`` bytes held in ``directory`` until ``release()``. Where even the reserve
    does not fit, ``held`` is False and ``error`` says why: the run is refused before
    anything starts (it could not record its end)."""

    def __init__(self, directory: Path, name: str, size: int = RESERVE_BYTES):
        self.path = Path(directory) / f".reserved-{name}"
        self.held, self.error = False, ""
        try:
            with open(self.path, "wb") as fh:
                try:                         # blocks allocated: zeros alone reserve nothing where they compress
                    os.posix_fallocate(fh.fileno(), 0, size)
                except OSError as exc:
                    if disk_full(exc):
                        raise
                    fh.write(b"\0" * size)  # a filesystem without fallocate
                fh.flush()
                os.fsync(fh.fileno())
            self.held = True
        except OSError as exc:
            self.path.unlink(missing_ok=True)
            self.error = f"{self.path.parent}: cannot set aside {size} bytes for the end of the run: {exc.strerror}"

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False
