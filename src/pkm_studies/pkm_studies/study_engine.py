"""``pkm-study``: a study's runs on Dask distributed (study.py says what a study is).

    pkm-study archi_leg_errors                      # config/studies/<name>.yaml, or a file
    pkm-study my_study.yaml --workers 2 --out studies/mine
    pkm-study my_study.yaml --scheduler tcp://10.0.0.5:8786

The engine is Dask's: a ``LocalCluster`` of ``--workers`` processes (one thread each)
by default, or the scheduler of a cluster of machines that have the project installed
at the same path (README, "Studies on a cluster"). Each run is a task (on a
LocalCluster, short direct runs go in batches of up to RUNS_PER_TASK: runs_per_task);
the worker runs each complete: in the direct engine (pkm_bringup.direct: the graph's
run, without a transport) where its scenario allows it (lockstep, the simulated machine) unless the
study says ``engine: graph``; as a graph in one process (``in_process: false``: its
nodes as processes) in a DDS domain its process holds alone on its host
(pkm_common.domains); one run at a time per worker process, into the run directory
``<out>/runs/<key>`` on the worker's host (removed after a run that was not recorded,
or with ``keep_runs: false`` once its metrics are read, unless it failed; such a
run in the direct engine of at most memory.MAX_SECONDS writes no bag: its messages are
kept in memory and its metrics taken from them, the bag's exactly; a failed one's are
written as its bag, in its directory that is kept: pkm_recording.memory).

Nothing lost, nothing twice: the client writes each run's row to
``<out>/results/<key>.json`` (atomically) as it comes; started again, the study runs
only the runs without one (rows in ``results.parquet`` that ``results/`` lacks are
written back first: a checkout that keeps only the table resumes from it). A run's
key holds a hash of what it runs, so an edited study or base scenario never reuses an
old row for a changed run. A run that fails
(an error, a refused scenario) is a row with ``run.status: failed`` and its error; a
run whose worker dies is given by Dask to another worker, and after Dask's
``distributed.scheduler.allowed-failures`` deaths (3) it is recorded as failed, named
as such. Task keys are the run keys, so a study restarted against a persistent
scheduler joins the runs still in flight instead of starting them again.

At the end (or on Ctrl-C, with what is done) it writes ``results.parquet`` and
``results.csv`` (every run: its varied parameters and metrics), ``summary.csv`` (per
group of ``group_by``: runs, completed, tripped, failed, and count, mean, std, min,
median, max of each of ``metrics``) and the plots (study_tables.py). Exit codes: 0
every run done and none failed, 1 some failed, 2 a bad study, 130 interrupted.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

from distributed import KilledWorker
from tqdm import tqdm

from pkm_bringup.scenario import load_scenario
from pkm_studies.dask_runner import (SchedulerUnreachable, StudyBusy, completed_on_dask, done_keys, study_lock,
                                     task_prefix, write_json_atomic)
from pkm_studies.design_study import format_front, run_design
from pkm_studies.run_task import RunTask, execute_run, execute_runs
from pkm_studies.study import Study, StudyError, describe, failed_metrics, load_study, result_row
from pkm_studies.study_tables import format_summary, rows_from_table, write_outputs

RUNS_PER_TASK = 8            # runs_per_task's largest batch
BATCH_SIMULATED_S = 5.0      # ... of runs of at most this much simulated time


def run_study(study: Study, out_dir: Path, workers: int | None = None, scheduler: str | None = None,
              progress: bool = True, stream=sys.stderr) -> dict:
    """Every run of ``study`` without a result in ``out_dir``, on Dask; then the tables
    and plots. Returns {"runs", "done_before", "ran", "failed", "interrupted", "table"}."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "results").mkdir(exist_ok=True)
    shutil.copyfile(study.source, out_dir / "study.yaml")
    runs = study.runs()
    restore_rows(out_dir, {r.key for r in runs})
    done = done_keys(out_dir)
    pending = run_order(runs, done)
    outcome = {"runs": len(runs), "done_before": len(runs) - len(pending), "ran": 0, "failed": 0,
               "interrupted": False, "not_run": [], "started": time.monotonic(), "finished_at": [],
               "batches": []}               # batches: (when, runs) of each task's rows, as they came
    if pending:
        bar = tqdm(total=len(runs), initial=outcome["done_before"], unit="run", disable=not progress, file=stream,
                   desc=study.name, smoothing=0.1)
        try:
            def task(r):
                return RunTask(str(study.scenario), r.overrides, str(out_dir.resolve() / "runs" / r.key),
                               study.in_process, study.engine, study.keep_runs)
            prefix = task_prefix("study", study.name, out_dir)
            size = runs_per_task(study, pending, workers, scheduler)
            singles = pending
            if size > 1:                     # batches first; a batch Dask gave up on, one run per task
                singles = []
                batches = [pending[i:i + size] for i in range(0, len(pending), size)]
                for i, future in completed_on_dask(execute_runs, [[[task(r) for r in b] for b in batches]],
                                                   [f"{prefix}{b[0].key}+{len(b) - 1}" for b in batches],
                                                   workers, scheduler):
                    results, problem, killed = _results_of(future)
                    if killed:               # which run killed its worker: each is tried alone
                        singles += batches[i]
                        continue
                    for run, metrics in zip(batches[i], results or [None] * len(batches[i])):
                        _take(study, out_dir, outcome, bar, run, metrics, problem)
                    outcome["batches"].append((time.monotonic(), len(batches[i])))
            if singles:
                for i, future in completed_on_dask(execute_run, [[task(r) for r in singles]],
                                                   [prefix + r.key for r in singles], workers, scheduler):
                    metrics, problem = _metrics_of(future)
                    _take(study, out_dir, outcome, bar, singles[i], metrics, problem)
                    outcome["batches"].append((time.monotonic(), 1))
        except KeyboardInterrupt:
            outcome["interrupted"] = True
        finally:
            bar.close()
    outcome["table"] = write_outputs(study, out_dir, runs)
    outcome["failed_total"] = int((outcome["table"]["run.status"] == "failed").sum()) \
        if "run.status" in outcome["table"] else 0
    return outcome


def _take(study: Study, out_dir: Path, outcome: dict, bar, run, metrics: dict | None, problem: str) -> None:
    """A run's metrics as its row (written atomically), counted; None: not the run's
    failure, no row (it runs when the study is started again)."""
    if metrics is None:
        outcome["not_run"].append(f"{run.key}: {problem}")
        return
    row = result_row(run, metrics)
    write_json_atomic(out_dir / "results" / f"{run.key}.json", {k: row[k] for k in study.row_columns(row)})
    outcome["ran"] += 1
    outcome["finished_at"].append((time.monotonic(), run.key))
    outcome["failed"] += metrics.get("run.status") == "failed"
    bar.set_postfix_str(f"failed {outcome['failed']}", refresh=False)
    bar.update()


def runs_per_task(study: Study, pending: list, workers: int | None, scheduler: str | None) -> int:
    """How many runs one Dask task takes. Each task costs its worker ~5 ms (its
    messages, the event loop beside the run: a 1 s run in the direct engine took 68-71
    ms a run one per task, 64-65 ms in one task); a batch pays it once. Short direct
    runs only (a run of at most BATCH_SIMULATED_S), at least 4 batches per worker
    (a study's last runs spread over its workers), and one per task on a scheduler of
    the user's (a study started again there joins the runs still in flight by their
    keys)."""
    if scheduler or study.engine == "graph" or len(pending) < 8:
        return 1
    try:
        duration = load_scenario(study.scenario, pending[0].overrides).duration_s
    except Exception:                  # noqa: BLE001 - the run's own refusal comes with its row
        return 1
    if duration > BATCH_SIMULATED_S:
        return 1
    return max(1, min(RUNS_PER_TASK, len(pending) // (4 * (workers or os.cpu_count() or 1))))


def _results_of(future) -> tuple[list | None, str, bool]:
    """(a batch's metrics, "", False); (None, why, True) when Dask gave up on it (its
    worker died each time); (None, why, False) for what is not the runs' failure
    (_metrics_of)."""
    try:
        return future.result(), "", False
    except KilledWorker as exc:
        return None, str(exc), True
    except Exception as exc:           # noqa: BLE001 - reported, the runs left to the next start
        return None, f"{type(exc).__name__}: {exc}", False


def run_order(runs: list, done: set) -> list:
    """The runs without a row, draw by draw across the grid's cells: a study stopped
    early (or still running) has the same draws in every cell, its groups compared on
    them (a Monte Carlo's strategies on the same machines), not the first cells whole."""
    return sorted((r for r in runs if r.key not in done), key=lambda r: (r.draw, r.cell))


def restore_rows(out_dir: Path, keys: set) -> int:
    """Rows of the study's runs that its table has and ``results/`` has not, written back
    (a study resumed from a checkout that keeps only results.parquet); how many."""
    restored = 0
    for key, row in rows_from_table(out_dir).items():
        path = out_dir / "results" / f"{key}.json"
        if key in keys and not path.exists():
            write_json_atomic(path, row)
            restored += 1
    return restored


def _metrics_of(future) -> tuple[dict | None, str]:
    """(the task's metrics, "") for a row; a run Dask gave up on (its worker died each
    time it was tried) is a failed run, named. Anything else (cancelled: the scheduler
    went away; a worker without a free domain or without rclpy) is not the run's
    failure: (None, why), no row, and the run runs when the study is started again."""
    try:
        return future.result(), ""
    except KilledWorker as exc:
        return failed_metrics(f"the run's worker died each time it was tried (Dask KilledWorker: {exc})"), ""
    except Exception as exc:           # noqa: BLE001 - reported, the run left to the next start
        return None, f"{type(exc).__name__}: {exc}"


# ------------------------------------------------------------------ command line
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-study", description=__doc__.split("\n\n")[0])
    parser.add_argument("study", help="study file, or the name of one in config/studies")
    parser.add_argument("--out", help="output directory (default: studies/<name>); a study started "
                                      "again there runs only what is missing")
    parser.add_argument("--workers", type=int, help="LocalCluster worker processes (default: one per core)")
    parser.add_argument("--scheduler", help="a Dask scheduler's address, e.g. tcp://HOST:8786, instead of a "
                                            "LocalCluster")
    parser.add_argument("--dry-run", action="store_true", help="list the runs and what is done; run nothing")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.workers is not None and not 1 <= args.workers <= 1024:
        print(f"pkm-study: --workers: must be in [1, 1024], got {args.workers}", file=sys.stderr)
        return 2
    if args.workers and args.scheduler:
        print("pkm-study: --workers and --scheduler exclude each other (the cluster has its own workers)",
              file=sys.stderr)
        return 2
    try:
        study = load_study(args.study)
    except StudyError as exc:
        print(f"pkm-study: {exc}", file=sys.stderr)
        return 2
    out_dir = Path(args.out or Path("studies") / study.name)
    try:
        with study_lock(out_dir):
            return _main_design(study, out_dir, args) if study.design is not None else _main_runs(study, out_dir, args)
    except (StudyBusy, SchedulerUnreachable) as exc:
        print(f"pkm-study: {exc}", file=sys.stderr)
        return 2


def _main_runs(study, out_dir: Path, args) -> int:
    runs = study.runs()
    done = done_keys(out_dir) | set(rows_from_table(out_dir))      # the table's rows: restored when it runs
    to_run = len(runs) - len(done & {r.key for r in runs})
    print(f"study {study.name}: {len(runs)} runs of {study.scenario.name} ({to_run} to run) -> {out_dir}", flush=True)
    if args.dry_run:
        for r in runs:
            print(f"  {r.key}  {'done ' if r.key in done else 'to do'}  {describe(r.values)}")
        return 0
    start = time.monotonic()
    outcome = run_study(study, out_dir, workers=args.workers, scheduler=args.scheduler,
                        progress=not args.no_progress)
    print(format_summary(study, outcome["table"]), flush=True)
    print(f"{outcome['ran']} runs in {time.monotonic() - start:.1f} s ({outcome['done_before']} done before), "
          f"{outcome['failed_total']} failed; written: {out_dir}/results.parquet, results.csv, summary.csv", flush=True)
    if outcome["interrupted"]:
        print(f"pkm-study: interrupted; {len(done_keys(out_dir) & {r.key for r in runs})} of {len(runs)} runs done: "
              "run the same command again to finish", file=sys.stderr)
        return 130
    if outcome["not_run"]:
        print(f"pkm-study: {len(outcome['not_run'])} runs not run, for reasons of the cluster, not of the runs "
              f"(run the same command again): {outcome['not_run'][0]}", file=sys.stderr)
        return 1
    return 1 if outcome["failed_total"] else 0


def _main_design(study, out_dir: Path, args) -> int:
    values = study.design_values()
    print(f"design sweep {study.name}: {len(values)} variants of {study.design['machine']} "
          f"({study.design['kind']}), chunks of {study.design['chunk']} -> {out_dir}", flush=True)
    if args.dry_run:
        return 0
    start = time.monotonic()
    outcome = run_design(study, out_dir, workers=args.workers, scheduler=args.scheduler,
                         progress=not args.no_progress)
    wall = time.monotonic() - start
    print(format_front(study, outcome["table"]), flush=True)
    rate = outcome["evaluations"] / outcome["cpu_s"] if outcome["cpu_s"] else float("nan")
    print(f"{outcome['ran']} of {outcome['chunks']} chunks in {wall:.1f} s ({outcome['done_before']} done before); "
          f"{outcome['evaluations']:.3g} pose evaluations, {rate:.3g} per CPU second; written: "
          f"{out_dir}/results.parquet, results.csv, pareto.csv", flush=True)
    if outcome["interrupted"]:
        print("pkm-study: interrupted: run the same command again to finish", file=sys.stderr)
        return 130
    if outcome["not_run"]:
        print(f"pkm-study: {len(outcome['not_run'])} chunks not computed (run the same command again): "
              f"{outcome['not_run'][0]}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
