"""pkm_studies.dask_runner.completed_on_dask hands each future over once and then
releases it: a worker keeps no result the study has taken (a study's worker grew by
~250 kB a run while every result of the study stayed in its memory)."""

from __future__ import annotations

import time

import pytest
from distributed import LocalCluster

from pkm_studies.dask_runner import completed_on_dask


def _result(i: int) -> bytes:
    time.sleep(0.05)                              # slower than the loop takes them
    return bytes(100_000) + i.to_bytes(4, "little")


@pytest.mark.slow
def test_a_taken_result_is_forgotten_by_its_worker():
    n = 24
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        worker = next(iter(cluster.workers.values()))
        held, seen = [], set()
        for i, future in completed_on_dask(_result, [range(n)], [f"pkm-test-{k}" for k in range(n)], None,
                                           cluster.scheduler_address):
            assert future.result()[-4:] == i.to_bytes(4, "little")
            seen.add(i)
            time.sleep(0.02)                      # the releases of the ones taken before reach the worker
            held.append(len(worker.data))
        assert seen == set(range(n))
        # without the release: 1, 2, ..., 24 results held; with it 1-2 (a few more when
        # the release messages lag behind on a loaded machine)
        assert max(held[n // 2:]) <= n // 3, held
