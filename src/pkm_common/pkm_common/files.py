"""Files a run writes on a disk that may fill up (pure, no rclpy): JSON written whole
or not at all (a temporary file, then an atomic rename), and a node's summary that a
full disk cannot turn into a crash."""

from __future__ import annotations

import contextlib
import contextvars
import errno
import json
import os
from pathlib import Path

__all__ = ["SUMMARY_BYTES", "atomic_write", "disk_full", "durable", "reserve_file", "scratch", "summary_written",
           "write_json", "write_summary"]

SUMMARY_BYTES = 64 * 1024          # what a node's summary may take, allocated when the node starts

_DURABLE = contextvars.ContextVar("pkm_files_durable", default=True)


@contextlib.contextmanager
def scratch():
    """Inside (this thread, this context): files are not forced to the disk and no
    space is set aside for them. For a directory read once and then removed (a study's
    run keeps only its metrics): a one-second run's fsyncs cost 2-3 ms on an idle
    disk, ~30 ms (a quarter of the run) on one busy with another study's writes. A
    reader still sees a file whole or not at all (the rename); only a power loss can
    lose one."""
    token = _DURABLE.set(False)
    try:
        yield
    finally:
        _DURABLE.reset(token)


def durable() -> bool:
    """Whether files written here are forced to the disk (False inside :func:`scratch`)."""
    return _DURABLE.get()


def disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` says the disk (or a quota) is full."""
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def atomic_write(path, write) -> None:
    """``write(tmp)`` a temporary file beside ``path``, flush it to the disk, then rename
    it to ``path``: a reader sees the old file or the whole new one, also after a crash
    or a full disk (OSError as it comes; the temporary file removed). The one way the
    project writes a file whole: JSON, metadata.yaml, tables, plots."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        if durable():
            fd = os.open(tmp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json(path, data, indent: int = 2) -> None:
    """``data`` as JSON to ``path``, whole or not at all (atomic_write)."""
    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=indent)
    atomic_write(path, write)


def reserve_file(path, size: int = SUMMARY_BYTES) -> bool:
    """Allocate ``size`` bytes for a file written at the end (a node's summary): a
    disk that fills up meanwhile (the recorder's bag) cannot take its place. The
    reserved file holds zeros, which no reader takes for JSON. False where it fails
    and inside :func:`scratch` (nothing reserved)."""
    if not durable():
        return False
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.posix_fallocate(fd, 0, size)
        finally:
            os.close(fd)
    except OSError:
        return False
    return True


def summary_written(path) -> bool:
    """Whether the node has written its summary (a reserved one holds zeros until then)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(1) == b"{"
    except OSError:
        return False


def write_summary(path, data, log_error) -> bool:
    """A node's summary file: into the blocks ``reserve_file`` allocated when it fits
    there (then truncated to its length), else whole or not at all (write_json). A
    disk that cannot take it is logged (``log_error(text)``) and False, never raised
    into the node's end."""
    path = Path(path)
    text = json.dumps(data, indent=2).encode()
    try:
        if path.is_file() and path.stat().st_size >= len(text):
            with open(path, "r+b") as fh:
                fh.write(text)
                fh.truncate()
                fh.flush()
                if durable():
                    os.fsync(fh.fileno())
        else:
            write_json(path, data)
    except OSError as exc:
        log_error(f"summary not written: {path}: {exc}")
        return False
    return True
