"""A run directory's files on a disk that may fill up (pure, no rclpy).

A full disk during a run left run.json empty, pkm-run in a traceback, and the nodes'
summaries empty. ``DiskReserve`` sets space aside when the run starts (a file of
zeros) and gives it back when the loop is over, before the nodes write their summaries
and pkm-run its run.json; ``write_json`` writes a file whole or not at all (a
temporary file, then an atomic rename), so a reader never finds half a run.json.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

__all__ = ["RESERVE_BYTES", "DiskReserve", "disk_full", "write_json"]

RESERVE_BYTES = 2 * 1024 * 1024      # the end of a run: summaries and run.json (~50 kB), the report's metrics
RESERVE_NAME = ".reserved"


def disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` says the disk (or a quota) is full."""
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def write_json(path: Path, data, indent: int = 2) -> None:
    """``data`` as JSON to ``path``, whole or not at all; OSError as it comes (the old
    file, if any, stays)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=indent)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class DiskReserve:
    """``size`` bytes held in ``directory`` until ``release()``. Where even the reserve
    does not fit, ``held`` is False and ``error`` says why: the run is refused before
    anything starts (it could not record its end)."""

    def __init__(self, directory: Path, size: int = RESERVE_BYTES):
        self.path = Path(directory) / RESERVE_NAME
        self.held, self.error = False, ""
        try:
            with open(self.path, "wb") as fh:
                fh.write(b"\0" * size)
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
