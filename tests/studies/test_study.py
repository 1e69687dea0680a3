"""Studies (pkm_studies.study, study_engine, study_tables): the study file, its runs and
draws, and whole studies on Dask: a LocalCluster interrupted and resumed, and a real
scheduler with two `dask worker` processes, one of them killed mid-study."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pkm_studies.study import StudyError, load_study, scenario_overrides
from pkm_studies.study_tables import summarise
from terminal import default_sigint      # tests/terminal.py

BIN = Path(sys.executable).parent


def _study(tmp_path: Path, **data) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"scenario": "mom3_square", **data}), encoding="utf-8")
    return path


# ------------------------------------------------------------------ the study file
@pytest.mark.parametrize("data, message", [
    ({"grids": {}}, "grids: unknown study key"),
    ({"grid": {"controller": ["x"]}}, "controller: name a parameter of the section"),
    ({"grid": {"dt_s.x": [1]}}, "dt_s.x: dt_s is not a node section"),
    ({"grid": {"speed": [1]}}, "speed: 'speed' is not a scenario key"),
    ({"grid": {"controller.strategy": []}}, "grid.controller.strategy: must be a non-empty list"),
    ({"sample": {"method": "sobol"}}, "sample.method: must be one of random, lhs"),
    ({"sample": {"runs": 0}}, r"sample.runs: must be an integer in \[1, 1000000\]"),
    ({"sample": {"parameters": {"dt_s": {"distribution": "uniform", "low": 2, "high": 1}}}},
     "sample.parameters.dt_s: low must be below high"),
    ({"sample": {"parameters": {"dt_s": {"distribution": "normal", "mean": 0, "sigma": 1}}}},
     "sample.parameters.dt_s.sigma: unknown"),
    ({"group_by": ["plant.seed"]}, "group_by: plant.seed is not a grid parameter"),
    ({"set": {"dt_s": 0.001}, "grid": {"dt_s": [0.001]}}, "dt_s: set in more than one"),
    ({"scenario": "nope"}, "scenario: no such scenario 'nope'"),
    ({"name": "../up"}, "name: letters, digits"),
    ({"set": {"settle_s": 0.1}, "group_by": ["settle_s"]}, "group_by: settle_s is not a grid parameter"),
    ({"engine": "fast"}, "engine: must be one of direct, graph"),
    ({"keep_runs": "no"}, "keep_runs: must be true or false"),
])
def test_a_bad_study_is_refused_naming_the_key(tmp_path, data, message):
    with pytest.raises(StudyError, match=message):
        load_study(_study(tmp_path, **data))


def test_a_grid_cell_the_scenario_refuses_is_refused_before_anything_runs(tmp_path):
    path = _study(tmp_path, grid={"controller.strategy": ["joint_pid", "magic"]})
    with pytest.raises(StudyError, match=r"run \w+ \(controller.strategy=magic\): .*strategy"):
        load_study(path)


def test_runs_are_the_grid_times_the_same_draws(tmp_path):
    study = load_study(_study(tmp_path, grid={"controller.strategy": ["joint_pid", "computed_torque"],
                                              "settle_s": [0.1, 0.2, 0.3]},
                              sample={"runs": 4, "seed": 5, "parameters": {
                                  "plant.link_length_errors": {"distribution": "normal", "mean": 0.0,
                                                               "std": 0.005, "size": 3}}}))
    runs = study.runs()
    assert len(runs) == 2 * 3 * 4 and len({r.key for r in runs}) == 24
    draws = [[r.values["plant.link_length_errors"] for r in runs if r.cell == c] for c in range(6)]
    assert all(d == draws[0] for d in draws) and len({tuple(v) for v in draws[0]}) == 4   # paired across cells
    assert [r.key for r in runs] == [r.key for r in load_study(study.source).runs()]        # seed alone decides
    # a section parameter replaces that parameter only: mom3_square's distribution is kept
    assert runs[5].overrides["controller"] == {"strategy": "joint_pid", "distribution": "pseudo_inverse"}
    assert runs[5].overrides["plant"]["compliance"] == [7.0e-7] * 3


def test_a_run_key_changes_with_what_it_runs(tmp_path):
    base = tmp_path / "base.yaml"
    shipped = Path(load_study(_study(tmp_path)).scenario)
    data = yaml.safe_load(shipped.read_text(encoding="utf-8"))
    data["program"] = str((shipped.parent / data["program"]).resolve())
    base.write_text(yaml.safe_dump(data), encoding="utf-8")
    keys = lambda **d: [r.key for r in load_study(_study(tmp_path, **{"scenario": "base.yaml", **d})).runs()]  # noqa: E731
    first = keys(grid={"settle_s": [0.1, 0.2]})
    assert keys(grid={"settle_s": [0.1, 0.2]}) == first
    assert keys(grid={"settle_s": [0.1, 0.25]})[0] == first[0] and keys(grid={"settle_s": [0.1, 0.25]})[1] != first[1]
    assert keys(grid={"settle_s": [0.05, 0.1, 0.2]})[1:] == first       # a value inserted: the others keep theirs
    assert len(set(keys(sample={"runs": 3}))) == 3                       # identical runs stay apart
    base.write_text(base.read_text(encoding="utf-8") + "\nsettle_s: 0.5\n", encoding="utf-8")
    assert not set(keys(grid={"settle_s": [0.1, 0.2]})) & set(first)     # an edited base scenario: all new


def test_latin_hypercube_draws_have_one_value_in_each_stratum(tmp_path):
    n = 40
    study = load_study(_study(tmp_path, sample={"method": "lhs", "runs": n, "seed": 2, "parameters": {
        "settle_s": {"distribution": "uniform", "low": 0.1, "high": 0.5},
        "plant.link_length_errors": {"distribution": "normal", "mean": 0.0, "std": 0.01, "size": 3}}}),
        check=False)
    values = study.sample_values()
    settle = np.array([v["settle_s"] for v in values])
    assert sorted(np.floor((settle - 0.1) / 0.4 * n).astype(int)) == list(range(n))
    from scipy.stats import norm
    for k in range(3):            # through the normal's CDF, each stratum of (0, 1) once as well
        u = norm.cdf(np.array([v["plant.link_length_errors"][k] for v in values]) / 0.01)
        assert sorted(np.floor(u * n).astype(int)) == list(range(n))


def test_random_normal_draws_have_the_asked_mean_and_spread(tmp_path):
    study = load_study(_study(tmp_path, sample={"runs": 4000, "seed": 9, "parameters": {
        "settle_s": {"distribution": "normal", "mean": 0.3, "std": 0.02}}}), check=False)
    x = np.array([v["settle_s"] for v in study.sample_values()])
    assert abs(x.mean() - 0.3) < 4 * 0.02 / np.sqrt(len(x)) and abs(x.std() / 0.02 - 1) < 0.05


@pytest.mark.parametrize("name", ["archi_leg_errors", "mom3_load_sweep", "sliding_star_design"])
def test_the_example_studies_load_with_every_grid_cell_accepted(name):
    study = load_study(name)
    size = study.design_values().shape if study.design else len(study.runs())
    assert size == {"archi_leg_errors": 90, "mom3_load_sweep": 8, "sliding_star_design": (100000, 3)}[name]


def test_overrides_refuse_a_section_that_is_not_a_mapping():
    with pytest.raises(StudyError, match="plant.seed: the base scenario's plant is not a mapping"):
        scenario_overrides({"plant": [1]}, {"plant.seed": 3})


def test_the_summary_counts_statuses_and_summarises_the_runs_that_did_not_fail(tmp_path):
    study = load_study(_study(tmp_path, grid={"controller.strategy": ["joint_pid", "computed_torque"]},
                              metrics=["m"]), check=False)
    frame = pd.DataFrame({"controller.strategy": ["joint_pid"] * 3 + ["computed_torque"] * 2,
                          "run.status": ["completed", "tripped", "failed", "completed", "completed"],
                          "m": [1.0, 3.0, 100.0, 2.0, 4.0]})
    summary = summarise(study, frame).set_index("group")
    a, b = summary.loc["strategy=joint_pid"], summary.loc["strategy=computed_torque"]
    assert (a["runs"], a["completed"], a["tripped"], a["failed"]) == (3, 1, 1, 1)
    assert (a["m.count"], a["m.mean"], a["m.max"]) == (2, 2.0, 3.0)       # the failed run's 100 left out
    assert b["m.std"] == pytest.approx(np.std([2.0, 4.0], ddof=1))
    # the tails: numpy's percentile (linear interpolation) of the runs that did not fail
    assert (a["m.p95"], a["m.p99"]) == pytest.approx((np.percentile([1.0, 3.0], 95), np.percentile([1.0, 3.0], 99)))
    assert a["m.p99"] == pytest.approx(2.98)


def test_only_a_run_dask_gave_up_on_is_a_failed_row():
    """A KilledWorker (its worker died each time) is the run's failure, a row; a task
    cancelled (the scheduler went away) or a worker's own error is not: no row, and
    the run runs when the study is started again."""
    from distributed import KilledWorker
    from pkm_studies.study_engine import _metrics_of

    class Done:
        def __init__(self, error):
            self.error = error

        def result(self):
            raise self.error
    from types import SimpleNamespace
    metrics, why = _metrics_of(Done(KilledWorker("pkm-study-x", SimpleNamespace(address="tcp://w"), 3)))
    assert metrics["run.status"] == "failed" and "worker died each time" in metrics["run.error"] and not why
    from distributed.client import FutureCancelledError
    for error in (FutureCancelledError("k", "scheduler-connection-lost"), RuntimeError("all 119 ROS domain IDs")):
        metrics, why = _metrics_of(Done(error))
        assert metrics is None and type(error).__name__ in why


# ------------------------------------------------------------------ whole studies
TINY = {"scenario": "mom3_square", "set": {"duration_s": 0.25, "record": False},
        "grid": {"controller.strategy": ["joint_pid", "computed_torque"]},
        "sample": {"runs": 3, "seed": 1, "parameters": {
            "plant.link_length_errors": {"distribution": "normal", "mean": 0.0, "std": 0.0005, "size": 3}}},
        "metrics": ["controller.max_tracking_error_m"]}


def _results(out: Path) -> dict[str, float]:
    return {p.stem: p.stat().st_mtime_ns for p in (out / "results").glob("*.json")}


def _row_workers(out: Path) -> set[str]:
    """The workers (run.worker) of the rows written so far."""
    workers = set()
    for p in (out / "results").glob("*.json"):
        try:
            workers.add(json.loads(p.read_text(encoding="utf-8")).get("run.worker"))
        except (OSError, ValueError):        # being written
            pass
    return workers - {None}


def _wait_for(predicate, timeout_s: float, what: str):
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.1)


@pytest.mark.slow
def test_an_interrupted_study_resumes_running_only_what_is_missing(tmp_path):
    """pkm-study on a LocalCluster of two workers, Ctrl-C after its first rows; started
    again it runs the rest only: every run has one row, the early rows untouched; the
    Parquet table and the CSV agree."""
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump({"name": "tiny", **TINY}), encoding="utf-8")
    out = tmp_path / "out"
    cmd = [str(BIN / "pkm-study"), str(path), "--out", str(out), "--workers", "2", "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, preexec_fn=default_sigint)
    try:
        _wait_for(lambda: len(_results(out)) >= 1 or proc.poll() is not None, 120, "a first row")
        os.killpg(proc.pid, signal.SIGINT)                 # Ctrl-C at a terminal: the whole group
        text, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    before = _results(out)
    assert 1 <= len(before) < 6 and proc.returncode == 130, text
    assert "interrupted" in text and "run the same command again" in text
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"({len(before)} done before)" in done.stdout
    after = _results(out)
    assert len(after) == 6 and all(after[k] == t for k, t in before.items())     # nothing twice
    table = pd.read_parquet(out / "results.parquet")
    csv = pd.read_csv(out / "results.csv")
    assert list(table["key"]) == list(csv["key"]) and sorted(table["key"]) == sorted(after)
    assert list(table["index"]) == list(range(6))
    assert set(table["run.status"]) == {"completed"}
    np.testing.assert_allclose(table["controller.max_tracking_error_m"], csv["controller.max_tracking_error_m"])
    assert [json.loads(v) for v in csv["plant.link_length_errors"]] == [list(v) for v in
                                                                        table["plant.link_length_errors"]]
    summary = pd.read_csv(out / "summary.csv")
    assert list(summary["runs"]) == [3, 3] and (out / "controller.max_tracking_error_m.png").stat().st_size > 1000


@pytest.mark.slow
def test_a_study_on_a_scheduler_with_two_workers_survives_a_killed_worker(tmp_path):
    """A real Dask scheduler and two `dask worker` processes over TCP on localhost, as
    on a cluster; one worker is killed (its nanny and process, SIGKILL) after the first
    rows: the study still ends with every run done once, none failed, and the runs
    that shared the workers' time had their own DDS domains (graph runs: the direct
    engine has none)."""
    from pkm_studies.study import load_study as load
    from pkm_studies.study_engine import run_study
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump({"name": "tiny_remote", **TINY, "engine": "graph",
                                    "sample": {**TINY["sample"], "runs": 4}}), encoding="utf-8")
    scheduler_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(scheduler_file)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    try:
        _wait_for(scheduler_file.exists, 60, "the scheduler file")
        for _ in range(2):
            procs.append(subprocess.Popen([str(BIN / "dask"), "worker", "--nthreads", "1", "--no-dashboard",
                                           "--scheduler-file", str(scheduler_file)],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          start_new_session=True))
        address = json.loads(scheduler_file.read_text())["address"]
        from distributed import Client
        with Client(address, timeout=60) as client:    # both workers up before the study: on a loaded
            client.wait_for_workers(2, timeout=120)      # machine one came late and did no run at all
        out = tmp_path / "out"
        killed = []

        def kill_one_worker():
            # rows from both workers first (on a loaded machine one worker once took the
            # first rows and was killed, leaving one worker in the table)
            _wait_for(lambda: len(_row_workers(out)) >= 2, 180, "rows from both workers")
            os.killpg(procs[1].pid, signal.SIGKILL)
            killed.append(len(_results(out)))
        killer = threading.Thread(target=kill_one_worker, daemon=True)
        killer.start()
        outcome = run_study(load(path), out, scheduler=address, progress=False)
        killer.join(timeout=5)
    finally:
        for p in procs:
            with_group = p.pid
            try:
                os.killpg(with_group, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait()
    assert killed and killed[0] < 8, "the worker was not killed mid-study"
    table = outcome["table"]
    assert len(table) == 8 and outcome["failed_total"] == 0 and set(table["run.status"]) == {"completed"}
    assert len(_results(out)) == 8
    workers = table.groupby("run.worker")["run.domain_id"].unique()
    assert len(workers) >= 2
    firsts = [d[0] for d in workers]
    assert all(len(d) == 1 for d in workers) and len(set(firsts)) == len(firsts)   # one domain each, never shared


# ------------------------------------------------------------------ design sweeps
DESIGN = {"design": {"machine": "sliding_star", "kind": "planar", "points_per_axis": 5, "theta_points": 3,
                     "chunk": 40},
          "grid": {"link_length_scale": [0.9, 1.1]},
          "sample": {"method": "lhs", "runs": 50, "seed": 4,
                     "parameters": {"platform_scale": {"distribution": "uniform", "low": 0.7, "high": 1.3}}},
          "objectives": {"cond_max": "min", "travel_max_m": "min"}}


def _design_study(tmp_path: Path, **changes) -> Path:
    path = tmp_path / "d.yaml"
    path.write_text(yaml.safe_dump({**DESIGN, **changes}), encoding="utf-8")
    return path


@pytest.mark.parametrize("changes, message", [
    ({"design": {"machine": "mom3", "kind": "planar"}}, "design.kind: planar, but machine mom3 is translational"),
    ({"design": {"machine": "sliding_star", "kind": "gough"}},
     "design.kind: gough, but machine sliding_star has no metrology"),
    ({"grid": {"wheel_base": [1.0]}}, "wheel_base: not a planar design parameter"),
    ({"objectives": {"speed": "min"}}, "objectives.speed: not a planar design metric"),
    ({"objectives": {"cond_max": "lowest"}}, "objectives.cond_max: must be min or max"),
    ({"scenario": "mom3_square"}, "scenario: a design sweep"),
    ({"design": {"machine": "config/machines/sliding_star.yaml"}}, "design.machine: the name of a machine"),
    ({"grid": {"link_length_scale": [0.9, -1.0]}}, r"grid.link_length_scale: values must be numbers in \(0, 10\)"),
    ({"grid": {"link_length_scale": ["long"]}}, "grid.link_length_scale: values must be numbers"),
    ({"sample": {"runs": 5, "parameters": {"platform_scale": {"distribution": "normal", "mean": 1.0, "std": 0.3}}}},
     r"sample.parameters.platform_scale: draws must stay in \(0, 10\); this normal draw spans \[-0.8, 2.8\]"),
])
def test_a_bad_design_sweep_is_refused_naming_the_key(tmp_path, changes, message):
    with pytest.raises(StudyError, match=message):
        load_study(_design_study(tmp_path, **changes))


def test_a_design_sweep_is_computed_in_chunks_resumed_and_has_its_pareto_front(tmp_path):
    """On a LocalCluster of one worker: 100 variants in 3 chunks; the table's metrics are
    those of pkm_kinematics.design directly; a chunk lost is the only one computed again."""
    from pkm_studies.design_study import run_design
    from pkm_kinematics import load_machine
    from pkm_kinematics.design import pareto_front, planar_metrics, workspace_poses
    study = load_study(_design_study(tmp_path))
    out = tmp_path / "out"
    first = run_design(study, out, workers=1, progress=False)
    table = first["table"]
    assert (first["variants"], first["chunks"], first["ran"]) == (100, 3, 3) and len(table) == 100
    machine = load_machine("sliding_star").model
    ref = planar_metrics(machine, study.varied, study.design_values(), workspace_poses(machine, 5, 3))
    np.testing.assert_array_equal(table["cond_max"], ref["cond_max"])
    assert list(table["link_length_scale"][:50]) == [0.9] * 50 and list(table["link_length_scale"][50:]) == [1.1] * 50
    assert np.array_equal(table["pareto"], pareto_front(np.c_[ref["cond_max"], ref["travel_max_m"]], ["min", "min"]))
    front = pd.read_csv(out / "pareto.csv")
    assert len(front) == table["pareto"].sum() and list(front["cond_max"]) == sorted(front["cond_max"])
    lost = sorted((out / "results").glob("*.npz"))[1]
    lost.unlink()
    again = run_design(study, out, workers=1, progress=False)
    assert (again["done_before"], again["ran"]) == (2, 1)
    pd.testing.assert_frame_equal(again["table"], table)
    assert pd.read_parquet(out / "results.parquet").shape == (100, len(table.columns))


# ------------------------------------------------------------------ the run's engine
def test_a_study_run_gives_the_same_row_in_the_direct_engine_as_in_the_graph(tmp_path):
    """A study's run (execute_run, as a worker runs it) in the direct engine by default
    and in the graph when asked: the same metrics, and the engine said in the row."""
    from pkm_studies.run_task import RunTask, execute_run
    study = load_study(_study(tmp_path, **{k: v for k, v in TINY.items() if k != "scenario"}))
    run = study.runs()[1]
    rows = {engine: execute_run(RunTask(str(study.scenario), run.overrides, str(tmp_path / engine), True, engine))
            for engine in ("", "graph")}
    assert rows[""]["run.engine"] == "direct" and rows["graph"]["run.engine"] == "graph"
    assert "run.domain_id" in rows["graph"] and "run.domain_id" not in rows[""]
    volatile = ("wall", "compute", "response", "steps_per_s", "task_s", "worker", "engine", "domain", "mode",
                "max_callback", "gap",
                # the graph's plant repeats its first state until its controller answers (discovery)
                "resent", "stale", "repeats", "gough_sensor.received", "gough_sensor.measured",
                # the direct engine solves no DKM pose that nothing reads (an unrecorded run)
                "gough_sensor.solved", "gough_sensor.dkm_run")
    same = {k: v for k, v in rows["graph"].items() if not any(w in k for w in volatile)}
    assert rows[""]["run.status"] == "completed", rows[""].get("run.error")
    assert len(same) > 20 and {k: rows[""].get(k) for k in same} == same
    assert rows[""]["controller.max_tracking_error_m"] > 0.0


def test_a_recorded_run_of_a_study_that_keeps_no_runs_leaves_its_metrics_and_no_directory(tmp_path):
    """keep_runs: false (a Monte Carlo of thousands of recorded runs, ~3 MB of bag
    each): the report's metrics are in the row, the run's directory is gone and nothing
    of it was forced to the disk (files.scratch); a study that keeps them keeps it,
    flushed."""
    from pkm_studies.run_task import RunTask, execute_run
    study = load_study(_study(tmp_path, **{**{k: v for k, v in TINY.items() if k != "scenario"},
                                           "set": {"duration_s": 0.2, "record": True}, "keep_runs": False}))
    assert study.keep_runs is False
    run = study.runs()[0]
    real_fsync = os.fsync
    for keep in (False, True):
        synced = []
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(os, "fsync", lambda fd: synced.append(fd) or real_fsync(fd))
            row = execute_run(RunTask(str(study.scenario), run.overrides, str(tmp_path / str(keep)), True, "", keep))
        assert row["run.status"] == "completed" and row["report.tracking_error.max_m"] > 0.0, row.get("run.error")
        assert (tmp_path / str(keep) / "bag").is_dir() == keep
        assert (len(synced) > 0) == keep, (keep, synced)
    # a run whose bag goes to the disk (longer than memory.MAX_SECONDS) keeps its space set
    # aside against a full disk, flushed, though its directory is removed after
    from pkm_studies import run_task
    synced = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(os, "fsync", lambda fd: synced.append(fd) or real_fsync(fd))
        patch.setattr(run_task, "MAX_SECONDS", 0.1)
        row = execute_run(RunTask(str(study.scenario), run.overrides, str(tmp_path / "long"), True, "", False))
    assert row["run.status"] == "completed" and row["report.tracking_error.max_m"] > 0.0, row.get("run.error")
    assert not (tmp_path / "long").exists() and synced


def test_a_study_resumes_from_its_table_alone(tmp_path):
    """A long study carried over clean checkouts keeps only results.parquet: its rows
    come back as they were written (floats to the bit, lists, a row's missing cells
    still missing) and count as done."""
    from pkm_studies.study_engine import restore_rows
    from pkm_studies.study_tables import write_outputs
    study = load_study(_study(tmp_path, grid={"controller.strategy": ["joint_pid", "computed_torque"]},
                              metrics=["m"]), check=False)
    runs = study.runs()
    out = tmp_path / "out"
    (out / "results").mkdir(parents=True)
    rows = {runs[0].key: {"key": runs[0].key, "index": 0, "run.status": "completed", "m": 0.1 + 0.2,
                          "plant.link_length_errors": [1e-3 / 3, -2.5e-3], "controller.strategy": "joint_pid"},
            runs[1].key: {"key": runs[1].key, "index": 1, "run.status": "failed", "run.error": "boom",
                          "controller.strategy": "computed_torque"}}
    for key, row in rows.items():
        (out / "results" / f"{key}.json").write_text(json.dumps(row), encoding="utf-8")
    write_outputs(study, out, runs)
    for p in (out / "results").glob("*.json"):
        p.unlink()
    assert restore_rows(out, {r.key for r in runs}) == 2
    again = {p.stem: json.loads(p.read_text(encoding="utf-8")) for p in (out / "results").glob("*.json")}
    assert again == rows
    assert restore_rows(out, {r.key for r in runs}) == 0            # present rows are left alone


def test_a_study_runs_draw_by_draw_across_its_cells(tmp_path):
    """Stopped early, a study has compared its groups on the same draws."""
    from pkm_studies.study_engine import run_order
    study = load_study(_study(tmp_path, grid={"controller.strategy": ["joint_pid", "computed_torque"]},
                              sample={"runs": 3, "parameters": {"dt_s": {"distribution": "uniform", "low": 0.001,
                                                                          "high": 0.002}}}), check=False)
    runs = study.runs()
    assert [(r.cell, r.draw) for r in runs] == [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)]
    order = run_order(runs, {runs[0].key})
    assert [(r.cell, r.draw) for r in order] == [(1, 0), (0, 1), (1, 1), (0, 2), (1, 2)]


def test_a_study_of_metrics_rows_keeps_the_status_and_its_metrics_only(tmp_path):
    from pkm_studies.study_tables import write_outputs
    study = load_study(_study(tmp_path, grid={"controller.strategy": ["joint_pid"]}, metrics=["m"], rows="metrics"),
                       check=False)
    run = study.runs()[0]
    row = {"key": run.key, "index": 0, "cell": 0, "draw": 0, "controller.strategy": "joint_pid",
           "run.status": "completed", "run.cause": "none", "run.wall_s": 1.0, "m": 2.0, "controller.cycles": 5}
    assert study.row_columns(row) == ["key", "index", "cell", "draw", "controller.strategy", "run.status",
                                      "run.cause", "m"]
    out = tmp_path / "out"
    (out / "results").mkdir(parents=True)
    (out / "results" / f"{run.key}.json").write_text(json.dumps(row), encoding="utf-8")   # a row of before
    table = write_outputs(study, out, [run])
    assert list(table.columns) == study.row_columns(row)
    with pytest.raises(StudyError, match="rows: must be one of all, metrics"):
        load_study(_study(tmp_path, rows="some"), check=False)


def test_short_direct_runs_go_to_the_workers_in_batches(tmp_path):
    """runs_per_task: up to RUNS_PER_TASK short direct runs a task, at least four tasks
    per worker; one run a task on a user's scheduler, for the graph, for long runs and
    for a handful of runs. A batch Dask gave up on is told apart (its runs are then
    tried one per task)."""
    from types import SimpleNamespace

    from distributed import KilledWorker
    from pkm_studies.study_engine import RUNS_PER_TASK, _results_of, runs_per_task
    study = load_study(_study(tmp_path, set={"duration_s": 1.0}, sample={"runs": 100, "parameters": {
        "dt_s": {"distribution": "uniform", "low": 0.001, "high": 0.002}}}), check=False)
    runs = study.runs()
    assert runs_per_task(study, runs, 1, None) == RUNS_PER_TASK == 8
    assert runs_per_task(study, runs[:40], 2, None) == 5 and runs_per_task(study, runs[:12], 1, None) == 3
    assert runs_per_task(study, runs[:7], 1, None) == 1                        # a handful
    assert runs_per_task(study, runs, 1, "tcp://127.0.0.1:8786") == 1            # a user's scheduler
    study.engine = "graph"
    assert runs_per_task(study, runs, 1, None) == 1
    study.engine = ""
    long = load_study(_study(tmp_path, set={"duration_s": 20.0}, sample={"runs": 100, "parameters": {
        "dt_s": {"distribution": "uniform", "low": 0.001, "high": 0.002}}}), check=False)
    assert runs_per_task(long, long.runs(), 1, None) == 1

    class Done:
        def __init__(self, error=None, value=None):
            self.error, self.value = error, value

        def result(self):
            if self.error is not None:
                raise self.error
            return self.value
    assert _results_of(Done(value=[{"a": 1}])) == ([{"a": 1}], "", False)
    results, why, killed = _results_of(Done(KilledWorker("pkm-study-x", SimpleNamespace(address="tcp://w"), 3)))
    assert results is None and killed and "pkm-study-x" in why
    results, why, killed = _results_of(Done(RuntimeError("all 119 ROS domain IDs")))
    assert results is None and not killed and "RuntimeError" in why


@pytest.mark.slow
def test_a_study_in_batches_has_the_rows_of_one_run_a_task(tmp_path, monkeypatch):
    """The same study run in batches (RUNS_PER_TASK) and one run a task: the same rows."""
    from pkm_studies import study_engine
    path = tmp_path / "batch.yaml"
    path.write_text(yaml.safe_dump({**TINY, "name": "batch", "set": {"duration_s": 0.05, "record": False},
                                    "sample": {**TINY["sample"], "runs": 8}}), encoding="utf-8")
    tables = {}
    for per_task in (8, 1):
        monkeypatch.setattr(study_engine, "RUNS_PER_TASK", per_task)
        outcome = study_engine.run_study(load_study(path), tmp_path / str(per_task), workers=1, progress=False)
        assert max(n for _, n in outcome["batches"]) == (4 if per_task == 8 else 1), outcome["batches"]
        tables[per_task] = outcome["table"].set_index("key").sort_index()
    columns = ["run.status", "controller.max_tracking_error_m", "controller.cycles", "sim_hw.steps"]
    assert len(tables[8]) == 16 and set(tables[8]["run.status"]) == {"completed"}
    pd.testing.assert_frame_equal(tables[8][columns], tables[1][columns])
