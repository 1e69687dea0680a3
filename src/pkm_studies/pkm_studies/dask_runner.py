"""Dask for the studies: the client (a LocalCluster or a scheduler's address), tasks
mapped and yielded as they complete, the output directory's lock, the task keys and
the rows kept as they come (study_engine.py for runs, design_study.py for design
sweeps)."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
from pathlib import Path

from dask.distributed import Client, LocalCluster, as_completed

from pkm_common.files import atomic_write


def write_json_atomic(path: Path, data) -> None:
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(data, indent=1, allow_nan=True), encoding="utf-8"))


def done_keys(out_dir: Path) -> set[str]:
    """The runs with a readable row; an unreadable one (a crash while the file system
    wrote it) is removed, and its run runs again."""
    done = set()
    for p in (out_dir / "results").glob("*.json"):
        try:
            json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            p.unlink(missing_ok=True)
            continue
        done.add(p.stem)
    return done


class StudyBusy(RuntimeError):
    """Another pkm-study works in the same output directory."""


@contextlib.contextmanager
def study_lock(out_dir: Path):
    """One client per output directory (``flock`` on ``<out>/.lock``, released by the
    kernel when the process ends): two would run the same missing runs twice."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".lock", "a+", encoding="utf-8") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise StudyBusy(f"another pkm-study is running in {out_dir}") from None
        yield


def task_prefix(kind: str, study_name: str, out_dir: Path) -> str:
    """Dask task keys: the run's key under the study and its output directory (a study
    run into two directories on one scheduler must not share results)."""
    where = hashlib.sha256(str(out_dir.resolve()).encode()).hexdigest()[:8]
    return f"pkm-{kind}-{study_name}-{where}-"


class SchedulerUnreachable(RuntimeError):
    """--scheduler names no scheduler that answers."""


def make_client(workers: int | None, scheduler: str | None):
    """(Client, its LocalCluster or None): the scheduler at ``scheduler``, else a
    LocalCluster of ``workers`` processes (default: one per core), one thread each. Its
    scheduler's HTTP server (the dashboard) takes a free port: Dask's default 8787 may be
    another cluster's, or another study's running beside it."""
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise SchedulerUnreachable(f"--scheduler {scheduler}: no Dask scheduler answers ({exc})") from None
    cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                           dashboard_address=":0", silence_logs=logging.ERROR)
    return Client(cluster), cluster


def completed_on_dask(function, iterables, keys: list, workers: int | None, scheduler: str | None):
    """``function`` mapped over ``iterables`` on a Dask client (make_client), one task
    per key: yields (position in the map, future) as they complete. The client (and its
    LocalCluster) is closed, the futures left cancelled, however the caller's loop ends
    (Ctrl-C inside the wait included: the KeyboardInterrupt goes on to the caller).
    A future is released once the caller's loop has taken it (its result read in the
    loop's body): the workers forget its result; kept to the end, a study's worker
    grew by ~250 kB a run. ``function`` must be reachable by its module's name (not
    defined in __main__), or cloudpickle sends it by value."""
    client = cluster = None
    futures = []
    try:
        client, cluster = make_client(workers, scheduler)
        futures = client.map(function, *iterables, key=keys, pure=False)
        position = {f.key: i for i, f in enumerate(futures)}
        for future in as_completed(futures):
            i = position[future.key]
            yield i, future
            futures[i] = None
            future.release()
    finally:
        if client is not None:
            client.cancel([f for f in futures if f is not None])
            client.close()
        if cluster is not None:
            cluster.close()
