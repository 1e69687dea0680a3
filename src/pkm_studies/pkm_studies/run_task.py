"""The worker's side of a study of runs: :class:`RunTask` (plain data, sent by pickle)
and :func:`execute_run`, the task Dask runs (study_engine.py maps it over a study's
runs; it lives in a module of its own so that Dask reaches it by its module's name
also when study_engine runs as ``python -m``)."""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import rclpy.logging

from pkm_bringup.direct import refusal
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import ScenarioError, load_scenario
from pkm_common.domains import use_private_domain
from pkm_common.files import scratch
from pkm_recording.memory import MAX_SECONDS, MemoryRecording
from pkm_runs.report import analyse_bag
from pkm_runs.report_metrics import metrics_dict
from pkm_studies.study import failed_metrics, run_metrics

_ONE_RUN_AT_A_TIME = threading.Lock()       # a worker process with several threads still runs one run at a time


@dataclass(frozen=True)
class RunTask:
    """What a worker needs for one run (plain data: sent to the worker by pickle)."""
    scenario: str               # the base scenario file (the same path on every worker)
    overrides: dict
    run_dir: str
    in_process: bool
    engine: str = ""            # direct | graph; "": direct where the scenario allows it (study.Study.engine)
    keep_run: bool = True       # a recorded run's directory kept once its metrics are read (study.Study.keep_runs)


def execute_run(task: RunTask) -> dict:
    """Run one study run on this worker and return its metrics (study.run_metrics), or
    ``failed_metrics`` with the error: never raises for a failing run. What fails
    around the run (no free DDS domain for a graph, rclpy missing on this worker)
    raises: it is the worker's fault, not the run's, and the study records no row for it."""
    with _ONE_RUN_AT_A_TIME:
        start = time.monotonic()
        where = {"run.worker": f"{socket.gethostname()}:{os.getpid()}"}
        try:
            s = load_scenario(task.scenario, task.overrides)
        except ScenarioError as exc:
            return {**failed_metrics(f"scenario refused: {exc}"), **where, "run.task_s": time.monotonic() - start}
        except Exception as exc:       # noqa: BLE001 - an unreadable program, ...: the run's failure, a row
            return {**failed_metrics(f"scenario not loaded: {type(exc).__name__}: {exc}"), **where,
                    "run.task_s": time.monotonic() - start}
        engine = task.engine or ("graph" if refusal(s) else "direct")
        where["run.engine"] = engine
        if engine == "graph":              # a graph's DDS domain, held by this process alone
            where["run.domain_id"] = use_private_domain(strict=True)
            _quiet_nodes()
        try:
            metrics = _execute(task, s, engine)
        except Exception as exc:       # noqa: BLE001 - a run's failure is a row, not a lost task
            metrics = failed_metrics(f"{type(exc).__name__}: {exc}")
        return {**metrics, **where, "run.task_s": time.monotonic() - start}


def execute_runs(tasks: list[RunTask]) -> list[dict]:
    """:func:`execute_run` of each task in turn, their metrics: a batch of short runs
    in one Dask task (study_engine.runs_per_task), whose cost is paid once a batch."""
    return [execute_run(task) for task in tasks]


def _quiet_nodes() -> None:
    # the nodes run in the worker: a thousand runs' lines, trips included, would bury the
    # progress bar; each row has the run's status, cause and reason (run.*)
    rclpy.logging.set_logger_level("pkm", rclpy.logging.LoggingSeverity.FATAL)


def _execute(task: RunTask, s, engine: str) -> dict:
    run_dir = Path(task.run_dir)
    shutil.rmtree(run_dir, ignore_errors=True)          # a run started again starts afresh
    # a bag that would be removed once read: the messages kept in memory, the metrics from them
    memory = engine == "direct" and s.record and not task.keep_run and s.duration_s <= MAX_SECONDS
    # a directory removed once read is not forced to the disk (a failed run's is kept, unflushed),
    # unless a bag goes to the disk: its run keeps the space set aside against a full one
    thrown_away = not s.record or not task.keep_run
    with scratch() if thrown_away and (not s.record or memory) else contextlib.nullcontext():
        run = run_scenario(s, run_dir, in_process=task.in_process, progress=False, report=False, engine=engine,
                           recording=MemoryRecording() if memory else None)
    report = run.pop("metrics", None) if memory else None
    if memory and report is None and run.get("report_error"):
        run["error"] = run.get("error") or f"report: {run['report_error']}"
    if not memory and s.record and (run_dir / "bag" / "metadata.yaml").exists():
        try:
            report = metrics_dict(analyse_bag(run_dir, namespace=run.get("namespace"),
                                              machine_name=run.get("machine")), run.get("published"))
        except (ValueError, OSError) as exc:
            run["error"] = run.get("error") or f"report: {exc}"
    metrics = run_metrics(run, report)
    if thrown_away and metrics.get("run.status") != "failed":
        shutil.rmtree(run_dir, ignore_errors=True)
    return metrics
