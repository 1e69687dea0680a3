"""Files a run writes on a disk that may fill up (pure, no rclpy): JSON written whole
or not at all (a temporary file, then an atomic rename), and a node's summary that a
full disk cannot turn into a crash."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

__all__ = ["disk_full", "write_json", "write_summary"]


def disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` says the disk (or a quota) is full."""
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def write_json(path, data, indent: int = 2) -> None:
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


def write_summary(path, data, log_error) -> bool:
    """A node's summary file (write_json); a disk that cannot take it is logged
    (``log_error(text)``) and False, never raised into the node's end."""
    try:
        write_json(path, data)
    except OSError as exc:
        log_error(f"summary not written: {path}: {exc}")
        return False
    return True
