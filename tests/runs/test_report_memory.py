"""The report's memory does not grow with the length of the run (benchmarks/report_memory.py).

Two synthetic ARCHI runs of 15 s and 45 s at 1 kHz (seven per-step streams, ~105k and
~315k messages) are recorded with the project's BagWriter and reported, each in a fresh
process that measures its own peak RSS. A report that keeps the run in memory grows by
hundreds of MB between the two; a streaming one by a few (the look-back of the stream
reader and the decimated curves are bounded)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

# loaded by path: benchmarks/ on sys.path would shadow names such as `controller`
_SPEC = importlib.util.spec_from_file_location(
    "pkm_benchmarks_report_memory", Path(__file__).resolve().parents[2] / "benchmarks" / "report_memory.py")
bench = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(bench)

GROWTH_LIMIT_MB = 40.0


@pytest.mark.slow
def test_report_memory_does_not_grow_with_the_length_of_the_run(tmp_path):
    measured = {}
    for seconds in (15.0, 45.0):
        run_dir = tmp_path / f"run_{seconds:g}s"
        written = bench.write_synthetic_run(run_dir, seconds)
        assert written["messages"] > 7 * 1000 * seconds
        measured[seconds] = bench.report_in_subprocess(run_dir, timeout_s=300)
        assert (run_dir / "report" / "metrics.json").is_file()
    growth = measured[45.0]["peak_rss_mb"] - measured[15.0]["peak_rss_mb"]
    assert growth < GROWTH_LIMIT_MB, measured
