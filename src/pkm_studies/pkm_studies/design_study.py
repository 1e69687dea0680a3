"""Design sweeps on Dask: a study with a ``design`` section (study.py) evaluates
kinematic variants of a machine (pkm_kinematics.design), in chunks of ``design.chunk``
variants per task, and writes the table and its Pareto front.

    design:
      machine: sliding_star           # config/machines
      kind: planar                    # planar: the actuated machine; gough: its Gough metrology
      points_per_axis: 11             # the workspace grid (planar: x, y; gough: the cube)
      theta_points: 9                 # planar: theta
      chunk: 2000                     # variants per task
    sample: {method: lhs, runs: 100000, seed: 1, parameters: {link_length_scale: {...}, ...}}
    objectives: {cond_max: min, reach: max, travel_max_m: min}

Outputs in the study's directory: ``results.parquet`` / ``results.csv`` (a row per
variant: its parameters, its metrics, ``pareto``), ``pareto.csv`` (the front, sorted by
the first objective), ``pareto_<a>_<b>.png`` (the first two objectives, the front
drawn over all variants). Like a study of runs, each chunk's result is kept as it
comes (``results/<key>.npz``, atomically; the key hashes the machine file, the grid
and the chunk's values) and a restart computes only the missing chunks.
"""

from __future__ import annotations

import hashlib
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from pkm_common.files import atomic_write
from pkm_kinematics import load_machine
from pkm_kinematics.config import config_dir
from pkm_kinematics.design import METRICS, gough_metrics, pareto_front, planar_metrics, workspace_poses
from pkm_studies.dask_runner import completed_on_dask, task_prefix
from pkm_studies.study import Study


def evaluate_chunk(design: dict, names: list, values: np.ndarray) -> dict:
    """The design metrics of ``values`` (V, len(names)) on the worker, with the CPU
    seconds it took (``cpu_s``)."""
    start = time.process_time()
    config = load_machine(design["machine"])
    if design["kind"] == "planar":
        poses = workspace_poses(config.model, design["points_per_axis"], design["theta_points"])
        out = planar_metrics(config.model, names, values, poses)
        evaluations = len(values) * len(poses)
    else:
        out = gough_metrics(config.metrology, names, values, design["points_per_axis"])
        evaluations = len(values) * design["points_per_axis"] ** 3
    return {**{k: np.asarray(v, dtype=float) for k, v in out.items()}, "cpu_s": time.process_time() - start,
            "evaluations": evaluations}


def chunk_keys(study: Study, values: np.ndarray) -> list[tuple[str, slice]]:
    """(key, rows) of each chunk: its index and a hash of the machine file, the design
    section, the parameter names, the metrics computed and the chunk's values."""
    machine_file = config_dir() / "machines" / f"{study.design['machine']}.yaml"
    base = hashlib.sha256(machine_file.read_bytes() + repr((sorted(study.design.items()), study.varied,
                                                            METRICS[study.design["kind"]])).encode())
    size = study.design["chunk"]
    out = []
    for i, start in enumerate(range(0, len(values), size)):
        rows = slice(start, min(start + size, len(values)))
        h = base.copy()
        h.update(np.ascontiguousarray(values[rows]).tobytes())
        out.append((f"{i:05d}-{h.hexdigest()[:10]}", rows))
    return out


def _readable(path: Path) -> bool:
    """A chunk's saved result that loads; an unreadable one is removed (computed again)."""
    if not path.exists():
        return False
    try:
        with np.load(path) as data:
            data["cpu_s"]
        return True
    except (OSError, ValueError, KeyError, EOFError):
        path.unlink(missing_ok=True)
        return False


def _save_npz(path: Path, data: dict) -> None:
    def write(tmp: Path):
        with open(tmp, "wb") as fh:                  # a file object: np.savez adds no suffix
            np.savez(fh, **data)
    atomic_write(path, write)


def run_design(study: Study, out_dir: Path, workers: int | None = None, scheduler: str | None = None,
               progress: bool = True, stream=sys.stderr) -> dict:
    """Every missing chunk on Dask, then the table, the front and the plot. Returns
    {"variants", "chunks", "done_before", "ran", "interrupted", "table", "cpu_s", "evaluations"}."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "results").mkdir(exist_ok=True)
    shutil.copyfile(study.source, out_dir / "study.yaml")
    values = study.design_values()
    chunks = chunk_keys(study, values)
    pending = [(k, rows) for k, rows in chunks if not _readable(out_dir / "results" / f"{k}.npz")]
    outcome = {"variants": len(values), "chunks": len(chunks), "done_before": len(chunks) - len(pending), "ran": 0,
               "interrupted": False, "not_run": [], "started": time.monotonic(), "finished_at": []}
    if pending:
        bar = tqdm(total=len(values), initial=sum(r.stop - r.start for k, r in chunks) -
                   sum(r.stop - r.start for k, r in pending), unit="variant", disable=not progress, file=stream,
                   desc=study.name, unit_scale=True)
        try:
            prefix = task_prefix("design", study.name, out_dir)
            iterables = [[study.design] * len(pending), [study.varied] * len(pending),
                         [values[rows] for _, rows in pending]]
            for i, future in completed_on_dask(evaluate_chunk, iterables, [prefix + k for k, _ in pending],
                                               workers, scheduler):
                k, rows = pending[i]
                try:
                    result = future.result()
                except Exception as exc:       # noqa: BLE001 - reported; the chunk is computed next time
                    outcome["not_run"].append(f"chunk {k}: {type(exc).__name__}: {exc}")
                    continue
                _save_npz(out_dir / "results" / f"{k}.npz", result)
                outcome["ran"] += 1
                outcome["finished_at"].append(time.monotonic())
                bar.update(rows.stop - rows.start)
        except KeyboardInterrupt:
            outcome["interrupted"] = True
        finally:
            bar.close()
    table, cpu_s, evaluations = assemble(study, out_dir, values, chunks)
    outcome.update(table=table, cpu_s=cpu_s, evaluations=evaluations)
    if len(table):
        write_outputs(study, out_dir, table)
    return outcome


def assemble(study: Study, out_dir: Path, values: np.ndarray, chunks) -> tuple[pd.DataFrame, float, int]:
    """The variants whose chunk is done: parameters, metrics and ``pareto`` (the front
    of ``study.objectives`` among them); the CPU seconds and pose evaluations they took."""
    parts, cpu_s, evaluations = [], 0.0, 0
    for k, rows in chunks:
        path = out_dir / "results" / f"{k}.npz"
        if not path.exists():
            continue
        with np.load(path) as data:
            frame = pd.DataFrame(values[rows], columns=study.varied)
            frame.insert(0, "variant", np.arange(rows.start, rows.stop))
            for name in data.files:
                if name not in ("cpu_s", "evaluations"):
                    frame[name] = data[name]
            cpu_s += float(data["cpu_s"])
            evaluations += int(data["evaluations"])
        parts.append(frame)
    if not parts:
        return pd.DataFrame(), cpu_s, evaluations
    table = pd.concat(parts, ignore_index=True)
    objectives = list(study.objectives)
    table["pareto"] = pareto_front(table[objectives].to_numpy(), [study.objectives[o] for o in objectives])
    return table, cpu_s, evaluations


def write_outputs(study: Study, out_dir: Path, table: pd.DataFrame) -> None:
    atomic_write(out_dir / "results.parquet", lambda p: table.to_parquet(p, engine="pyarrow", index=False))
    atomic_write(out_dir / "results.csv", lambda p: table.to_csv(p, index=False))
    first = list(study.objectives)[0]
    front = table[table["pareto"]].sort_values(first, ascending=study.objectives[first] == "min")
    atomic_write(out_dir / "pareto.csv", lambda p: front.to_csv(p, index=False))
    objectives = list(study.objectives)
    if len(objectives) >= 2:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        a, b = objectives[:2]
        fig, ax = plt.subplots(figsize=(6.0, 4.5))
        ax.plot(table[a], table[b], ".", ms=2, alpha=0.3, color="0.6", label=f"{len(table)} variants")
        ax.plot(front[a], front[b], "o", ms=4, color="C3", label=f"Pareto front ({len(front)})")
        for name, set_scale in ((a, ax.set_xscale), (b, ax.set_yscale)):
            finite = table[name][np.isfinite(table[name])]
            if len(finite) and finite.min() > 0 and finite.max() > 100 * finite.min():
                set_scale("log")              # condition numbers near a singularity span decades
        ax.set_xlabel(f"{a} ({study.objectives[a]})")
        ax.set_ylabel(f"{b} ({study.objectives[b]})")
        ax.set_title(f"{study.name}: {study.design['machine']} variants", fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        atomic_write(out_dir / f"pareto_{a}_{b}.png", lambda p: fig.savefig(p, dpi=110, format="png"))
        plt.close(fig)


def format_front(study: Study, table: pd.DataFrame, rows: int = 8) -> str:
    """The front's best rows by the first objective, as text."""
    if not len(table):
        return "no results"
    first = list(study.objectives)[0]
    front = table[table["pareto"]].sort_values(first, ascending=study.objectives[first] == "min")
    cols = study.varied + list(study.objectives)
    senses = ", ".join(f"{k} {v}" for k, v in study.objectives.items())
    return (f"Pareto front: {len(front)} of {len(table)} variants ({senses})\n"
            + front[cols].head(rows).to_string(index=False, float_format=lambda v: f"{v:.4g}"))
