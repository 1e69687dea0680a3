"""Studies: many runs of one scenario with parameters varied (pure; no rclpy, no Dask).

A study file (``config/studies/*.yaml``; ``pkm-study``, study_engine.py runs it)::

    name: archi_leg_errors            # names the output directory (default: the file's stem)
    description: ...
    scenario: archi_demo              # the base: a name in config/scenarios, or a file relative to this one
    set:                              # fixed for every run (dotted paths, below)
      record: true
    grid:                             # every combination of these values
      controller.strategy: [joint_pid, decentralized_projected]
    sample:                           # draws: the same draws in every grid cell (paired comparisons)
      method: random                  # random | lhs (Latin hypercube)
      runs: 30                        # draws per grid cell
      seed: 1
      parameters:
        plant.link_length_errors: {distribution: normal, mean: 0.0, std: 0.005, size: 4}
        controller.bandwidth_hz: {distribution: uniform, low: 20, high: 40}
    group_by: [controller.strategy]   # the summary's groups (default: the grid's parameters)
    metrics: [report.tracking_error.max_m, report.internal_force.max_n]   # summarised and plotted
    keep_runs: true                   # false: a recorded run's directory removed once its row is written
    rows: all                         # metrics: a row keeps its status and the metrics above only

A dotted path names a scenario key (``dt_s``, ``record``) or a parameter of one of its
node sections (``controller.strategy``, ``plant.link_length_errors``: scenario.SECTIONS);
``size: n`` draws a list of n independent values. The runs are the grid's cells times
the draws (a study with neither is one run). Every run's scenario goes through
``load_scenario``, which names a bad key or value; the grid's cells are checked before
anything starts.

A run's row holds its varied parameters, its status and the metrics: ``run.*`` (status,
cause, wall time), ``controller.*`` and ``sim_hw.*`` (the nodes' summaries: the
controller's own measured error, peak force, saturation count, deadline misses ...) and,
for a recorded run, ``report.*`` (the report's metrics: the true tracking error,
internal force ...; report_metrics.metrics_dict), nested keys joined with dots. With
``rows: metrics`` it keeps its key, draw, varied parameters, ``run.status``, ``cause``,
``trip_reason``, ``error`` and the study's ``metrics`` only (a Monte Carlo's table).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from itertools import product
from pathlib import Path

import numpy as np

from pkm_bringup.engines import ENGINES
from pkm_bringup.scenario import KEYS, SECTIONS, ScenarioError, load_scenario, read_mapping_file
from pkm_kinematics import load_machine
from pkm_kinematics.config import config_dir, machine_names
from pkm_kinematics.design import METRICS, PARAMETERS
from pkm_kinematics.task_space import PLANAR
from pkm_kinematics.yaml_files import read_yaml

STUDY_KEYS = ("name", "description", "scenario", "set", "grid", "sample", "group_by", "metrics", "in_process",
              "engine", "keep_runs", "rows", "design", "objectives")
DESIGN_KEYS = ("machine", "kind", "points_per_axis", "theta_points", "chunk")
SENSES = ("min", "max")
SAMPLE_KEYS = ("method", "runs", "seed", "parameters")
METHODS = ("random", "lhs")
DISTRIBUTIONS = {"normal": ("mean", "std"), "uniform": ("low", "high")}
DEFAULT_METRICS = ("report.tracking_error.max_m", "report.internal_force.max_n", "report.drive_force.peak_applied_n",
                   "controller.max_tracking_error_m", "controller.peak_drive_force_n")
MAX_RUNS = 1_000_000
ROWS = ("all", "metrics")                     # what a row keeps (Study.rows)
ROW_BASE = ("key", "index", "cell", "draw")
ROW_STATUS = ("run.status", "run.cause", "run.trip_reason", "run.error")


class StudyError(ValueError):
    """A study key is missing, unknown or out of range; the message names it."""


@dataclass(frozen=True)
class Draw:
    """How one sampled parameter is drawn: ``size`` values (a list when size > 1)."""
    path: str
    distribution: str
    a: float                     # mean | low
    b: float                     # std  | high
    size: int = 1

    def from_unit(self, u: np.ndarray):
        """Values from uniform variates ``u`` in (0, 1) (inverse CDF): one or a list."""
        from scipy.stats import norm
        x = self.a + self.b * norm.ppf(u) if self.distribution == "normal" else self.a + (self.b - self.a) * u
        values = [float(v) for v in x]
        return values[0] if self.size == 1 else values


@dataclass(frozen=True)
class RunSpec:
    """One run of a study: its key (a hash of what it runs: the base scenario's, its
    program's and its machine's files, the overrides and a repetition number, so that an
    edited study keeps the rows of the runs it still has and never takes an old row for
    a changed run), its place in the study and the scenario's overrides."""
    key: str
    index: int
    cell: int                    # grid cell
    draw: int                    # sample draw (0 without sampling)
    values: dict                 # dotted path -> value, the varied parameters
    overrides: dict              # load_scenario's top-level overrides


@dataclass
class Study:
    name: str
    source: Path
    scenario: Path                           # the base scenario file
    description: str = ""
    fixed: dict = field(default_factory=dict)
    grid: dict = field(default_factory=dict)  # path -> list of values
    method: str = "random"
    runs_per_cell: int = 1
    seed: int = 0
    draws: list = field(default_factory=list)  # [Draw]
    group_by: list = field(default_factory=list)
    metrics: list = field(default_factory=list)
    in_process: bool = True                  # the graph's nodes in one process (engine graph)
    engine: str = ""                         # direct | graph; "": direct where the run's scenario allows it
    keep_runs: bool = True                   # a recorded run's directory (its bag) kept after its metrics are read
    rows: str = "all"                        # all: every metric of a run in its row; metrics: status and metrics only
    design: dict | None = None                # a design sweep (design_study.py) instead of runs
    objectives: dict = field(default_factory=dict)    # design metric -> "min" | "max" (the Pareto front)

    def row_columns(self, columns) -> list:
        """The columns a row and the table keep of ``columns``: every one; with ``rows:
        metrics``, the run's key and place, its varied parameters, its status and the
        study's ``metrics`` (a table of 30 000 runs of ~190 columns is ~19 MB)."""
        if self.rows == "all":
            return list(columns)
        kept = {*ROW_BASE, *self.varied, *ROW_STATUS, *self.metrics}
        return [c for c in columns if c in kept]

    @property
    def varied(self) -> list[str]:
        return list(self.grid) + [d.path for d in self.draws]

    def runs(self) -> list[RunSpec]:
        """Every run, in a fixed order (grid cells in row-major order, the draws inside)."""
        base = _scenario_data(self.scenario)
        cells = [dict(zip(self.grid, combo)) for combo in product(*self.grid.values())] if self.grid else [{}]
        samples = self.sample_values()
        fingerprint = scenario_fingerprint(self.scenario, base)
        out, seen = [], {}
        for c, cell in enumerate(cells):
            for d, sample in enumerate(samples):
                values = {**cell, **sample}
                overrides = scenario_overrides(base, {**self.fixed, **values})
                what = json.dumps([fingerprint, overrides, self.in_process], sort_keys=True, default=str)
                repetition = seen[what] = seen.get(what, -1) + 1        # identical runs (no draws) stay apart
                key = hashlib.sha256(f"{what}#{repetition}".encode()).hexdigest()[:16]
                out.append(RunSpec(key, len(out), c, d, values, overrides))
        return out

    def design_values(self) -> np.ndarray:
        """A design sweep's variants, (V, len(varied)): the grid's cells times the draws."""
        cells = list(product(*self.grid.values())) if self.grid else [()]
        draws = self.sample_values()
        names = [d.path for d in self.draws]
        return np.array([[*cell, *(sample[n] for n in names)] for cell in cells for sample in draws],
                        dtype=float).reshape(len(cells) * len(draws), len(self.varied))

    def sample_values(self) -> list[dict]:
        """The draws (dotted path -> value), ``runs_per_cell`` of them ([{}] without
        sampling): from ``seed`` alone, so the same in every cell and on every resume."""
        if not self.draws:
            return [{}] * self.runs_per_cell
        dims = sum(d.size for d in self.draws)
        if self.method == "lhs":
            from scipy.stats import qmc
            u = qmc.LatinHypercube(d=dims, seed=self.seed).random(self.runs_per_cell)
        else:
            u = np.random.default_rng(self.seed).random((self.runs_per_cell, dims))
        u = np.clip(u, 1e-12, 1 - 1e-12)              # the normal's inverse CDF is infinite at 0 and 1
        out = []
        for row in u:
            values, col = {}, 0
            for d in self.draws:
                values[d.path] = d.from_unit(row[col:col + d.size])
                col += d.size
            out.append(values)
        return out


# ------------------------------------------------------------------ dotted paths
def _scenario_data(path: Path) -> dict:
    return read_yaml(path) or {}


def scenario_fingerprint(path: Path, data: dict) -> str:
    """A hash of the base scenario file and of the program and machine files it names
    (the node parameter files in config/ are not in it: after editing them, or the
    code, start the study in a new directory)."""
    h = hashlib.sha256(path.read_bytes())
    program = data.get("program")
    machine = str(data.get("machine", ""))
    for file in ((path.parent / str(program)) if program else None,
                 config_dir() / "machines" / f"{machine}.yaml" if machine in machine_names() else Path(machine)):
        if file is not None and file.is_file():
            h.update(file.read_bytes())
    return h.hexdigest()


def split_path(path: str) -> tuple[str, str | None]:
    """'controller.strategy' -> ('controller', 'strategy'); 'dt_s' -> ('dt_s', None)."""
    if not isinstance(path, str) or not path:
        raise StudyError(f"parameter path: must be a scenario key or section.parameter, got {path!r}")
    head, _, rest = path.partition(".")
    if head not in KEYS:
        raise StudyError(f"{path}: {head!r} is not a scenario key; allowed: {', '.join(KEYS)}")
    if rest and head not in SECTIONS:
        raise StudyError(f"{path}: {head} is not a node section ({', '.join(SECTIONS)}): it has no parameters")
    if not rest and head in SECTIONS:
        raise StudyError(f"{path}: name a parameter of the section, e.g. {head}.<parameter>")
    if "." in rest:
        raise StudyError(f"{path}: one level below a section only (section.parameter)")
    return head, rest or None


def scenario_overrides(base: dict, values: dict) -> dict:
    """load_scenario's top-level overrides for ``values`` (dotted path -> value) on the
    base scenario's data: a section parameter replaces that parameter only."""
    out: dict = {}
    for path, value in values.items():
        head, key = split_path(path)
        if key is None:
            out[head] = value
        else:
            section = out.setdefault(head, copy.deepcopy(base.get(head) or {}))
            if not isinstance(section, dict):
                raise StudyError(f"{path}: the base scenario's {head} is not a mapping")
            section[key] = value
    return out


# ------------------------------------------------------------------ the study file
def _positive_int(data: dict, key: str, default: int, hi: int, where: str) -> int:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= hi:
        raise StudyError(f"{where}{key}: must be an integer in [1, {hi}], got {value!r}")
    return value


def _draw(path: str, spec) -> Draw:
    where = f"sample.parameters.{path}"
    if not isinstance(spec, dict):
        raise StudyError(f"{where}: must be a mapping such as {{distribution: normal, mean: 0, std: 1}}")
    kind = spec.get("distribution")
    if kind not in DISTRIBUTIONS:
        raise StudyError(f"{where}.distribution: must be one of {', '.join(DISTRIBUTIONS)}, got {kind!r}")
    names = DISTRIBUTIONS[kind]
    unknown = sorted(set(spec) - {"distribution", "size", *names})
    if unknown:
        raise StudyError(f"{where}.{unknown[0]}: unknown; a {kind} draw takes {', '.join(names)} and size")
    a, b = (spec.get(n) for n in names)
    for n, v in zip(names, (a, b)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise StudyError(f"{where}.{n}: must be a finite number, got {v!r}")
    if kind == "normal" and b < 0:
        raise StudyError(f"{where}.std: must be >= 0, got {b!r}")
    if kind == "uniform" and not a < b:
        raise StudyError(f"{where}: low must be below high, got low {a!r}, high {b!r}")
    size = _positive_int(spec, "size", 1, 1000, f"{where}.")
    return Draw(path, kind, float(a), float(b), size)


def _resolve_scenario(value, source: Path) -> Path:
    if not isinstance(value, str) or not value:
        raise StudyError("scenario: required, the name of a file in config/scenarios or a scenario file")
    if value.endswith((".yaml", ".yml")):
        path = source.parent / value
    else:
        path = config_dir() / "scenarios" / f"{value}.yaml"
    if not path.is_file():
        raise StudyError(f"scenario: no such scenario {value!r} ({path})")
    return path.resolve()


def load_study(path: str | Path, check: bool = True) -> Study:
    """Read and validate a study file; with ``check``, every grid cell's scenario (with
    the first draw) goes through load_scenario, so that nothing starts on a bad study."""
    path, data = read_mapping_file(path, "studies", "study", StudyError)
    unknown = sorted(set(data) - set(STUDY_KEYS))
    if unknown:
        raise StudyError(f"{unknown[0]}: unknown study key; allowed: {', '.join(STUDY_KEYS)}")
    design = _design(data)
    if design is not None and "scenario" in data:
        raise StudyError("scenario: a design sweep (design) varies a machine, not a scenario: give one of them")
    name = str(data.get("name", path.stem))
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name) or name.startswith("."):
        raise StudyError(f"name: letters, digits, '_', '-' and '.' only (it names the output directory), got {name!r}")
    study = Study(name=name, source=path.resolve(),
                  scenario=_resolve_scenario(data.get("scenario"), path.resolve()) if design is None else Path(),
                  description=str(data.get("description", "")), design=design)
    check_path = split_path if design is None else _design_path_check(design["kind"])
    fixed = data.get("set") or {}
    grid = data.get("grid") or {}
    if design is not None and fixed:
        raise StudyError("set: a design sweep has no fixed scenario keys (its base is the machine file)")
    for key, value in (("set", fixed), ("grid", grid)):
        if not isinstance(value, dict):
            raise StudyError(f"{key}: must be a mapping of dotted paths")
        for p in value:
            check_path(p)
    for p, values in grid.items():
        if not isinstance(values, list) or not values:
            raise StudyError(f"grid.{p}: must be a non-empty list of values, got {values!r}")
    study.fixed, study.grid = dict(fixed), dict(grid)
    sample = data.get("sample")
    if sample is not None:
        if not isinstance(sample, dict):
            raise StudyError("sample: must be a mapping (method, runs, seed, parameters)")
        unknown = sorted(set(sample) - set(SAMPLE_KEYS))
        if unknown:
            raise StudyError(f"sample.{unknown[0]}: unknown; allowed: {', '.join(SAMPLE_KEYS)}")
        study.method = sample.get("method", "random")
        if study.method not in METHODS:
            raise StudyError(f"sample.method: must be one of {', '.join(METHODS)}, got {study.method!r}")
        study.runs_per_cell = _positive_int(sample, "runs", 1, MAX_RUNS, "sample.")
        seed = sample.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise StudyError(f"sample.seed: must be an integer >= 0, got {seed!r}")
        study.seed = seed
        params = sample.get("parameters") or {}
        if not isinstance(params, dict):
            raise StudyError("sample.parameters: must be a mapping of dotted path -> distribution")
        study.draws = [_draw(p, spec) for p, spec in params.items()]
        for d in study.draws:
            check_path(d.path)
            if design is not None and d.size != 1:
                raise StudyError(f"sample.parameters.{d.path}.size: a design parameter is one number")
    clash = sorted((set(study.grid) | set(study.fixed)) & {d.path for d in study.draws}) or \
        sorted(set(study.grid) & set(study.fixed))
    if clash:
        raise StudyError(f"{clash[0]}: set in more than one of set, grid and sample.parameters")
    total = math.prod(len(v) for v in study.grid.values()) * study.runs_per_cell
    if total > MAX_RUNS:
        raise StudyError(f"grid x sample.runs: {total} runs, more than {MAX_RUNS}")
    study.group_by = _names(data, "group_by", list(study.grid))
    bad = [g for g in study.group_by if g not in study.grid]
    if bad:
        raise StudyError(f"group_by: {bad[0]} is not a grid parameter ({', '.join(study.grid) or 'none'})")
    study.metrics = _names(data, "metrics", list(DEFAULT_METRICS) if design is None else [])
    if design is not None:
        _check_design_values(study)
        study.objectives = _objectives(data, design["kind"])
        study.metrics = study.metrics or list(study.objectives)
    elif "objectives" in data:
        raise StudyError("objectives: only a design sweep has objectives (its Pareto front)")
    in_process = data.get("in_process", True)
    if not isinstance(in_process, bool):
        raise StudyError(f"in_process: must be true or false, got {in_process!r}")
    study.in_process = in_process
    engine = data.get("engine", "")
    if engine not in ("", *ENGINES):
        raise StudyError(f"engine: must be one of {', '.join(ENGINES)} (default: direct where a run's scenario "
                         f"allows it, lockstep on the simulated machine; else graph), got {engine!r}")
    study.engine = engine
    keep = data.get("keep_runs", True)
    if not isinstance(keep, bool):
        raise StudyError(f"keep_runs: must be true or false (false: a recorded run's directory is removed once "
                         f"its metrics are in its row; a failed run's is kept), got {keep!r}")
    study.keep_runs = keep
    rows = data.get("rows", "all")
    if rows not in ROWS:
        raise StudyError(f"rows: must be one of {', '.join(ROWS)} (metrics: a row keeps the run's status and the "
                         f"study's metrics only), got {rows!r}")
    study.rows = rows
    if check and design is None:
        check_runs(study)
    return study


def _design(data: dict) -> dict | None:
    """The ``design`` section: machine (config/machines name), kind (planar: the actuated
    planar machine; gough: its Gough metrology), the workspace grid, the chunk size."""
    design = data.get("design")
    if design is None:
        return None
    if not isinstance(design, dict):
        raise StudyError("design: must be a mapping (machine, kind, points_per_axis, theta_points, chunk)")
    unknown = sorted(set(design) - set(DESIGN_KEYS))
    if unknown:
        raise StudyError(f"design.{unknown[0]}: unknown; allowed: {', '.join(DESIGN_KEYS)}")
    if design.get("machine") not in machine_names():
        raise StudyError(f"design.machine: the name of a machine in config/machines ({', '.join(machine_names())}), "
                         f"got {design.get('machine')!r}")
    config = load_machine(design["machine"])
    kind = design.get("kind", "planar")
    if kind not in ("planar", "gough"):
        raise StudyError(f"design.kind: must be planar or gough, got {kind!r}")
    if kind == "planar" and config.model.task_space is not PLANAR:
        raise StudyError(f"design.kind: planar, but machine {config.name} is {config.kind}")
    if kind == "gough" and config.metrology is None:
        raise StudyError(f"design.kind: gough, but machine {config.name} has no metrology section")
    out = {"machine": config.name, "kind": kind}
    for key, default, hi in (("points_per_axis", 11 if kind == "planar" else 3, 101), ("theta_points", 9, 361),
                             ("chunk", 2000 if kind == "planar" else 50, 1_000_000)):
        out[key] = _positive_int(design, key, default, hi, "design.")
    return out


def _check_design_values(study: Study) -> None:
    """Every grid value a number inside its parameter's range; a uniform draw inside it;
    a normal one within six standard deviations of its bounds (design.PARAMETERS)."""
    kind = study.design["kind"]
    for name, values in study.grid.items():
        lo, hi = PARAMETERS[kind][name][1]
        for v in values:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo < v < hi:
                raise StudyError(f"grid.{name}: values must be numbers in ({lo:g}, {hi:g}), got {v!r}")
    for d in study.draws:
        lo, hi = PARAMETERS[kind][d.path][1]
        low, high = (d.a, d.b) if d.distribution == "uniform" else (d.a - 6.0 * d.b, d.a + 6.0 * d.b)
        if not lo < low <= high < hi:
            raise StudyError(f"sample.parameters.{d.path}: draws must stay in ({lo:g}, {hi:g}); this "
                             f"{d.distribution} draw spans [{low:g}, {high:g}]"
                             + (" (mean +- 6 std)" if d.distribution == "normal" else ""))


def _design_path_check(kind: str):

    def check(name: str):
        if name not in PARAMETERS[kind]:
            raise StudyError(f"{name}: not a {kind} design parameter; known: {', '.join(PARAMETERS[kind])}")
    return check


def _objectives(data: dict, kind: str) -> dict:
    value = data.get("objectives")
    if not isinstance(value, dict) or not value:
        raise StudyError(f"objectives: required for a design sweep, a mapping of metric -> min | max; "
                         f"metrics: {', '.join(METRICS[kind])}")
    for name, sense in value.items():
        if name not in METRICS[kind]:
            raise StudyError(f"objectives.{name}: not a {kind} design metric; known: {', '.join(METRICS[kind])}")
        if sense not in SENSES:
            raise StudyError(f"objectives.{name}: must be min or max, got {sense!r}")
    return dict(value)


def _names(data: dict, key: str, default: list) -> list[str]:
    value = data.get(key, default)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise StudyError(f"{key}: must be a list of names, got {value!r}")
    return list(value)


def check_runs(study: Study) -> None:
    """Each grid cell's first run through load_scenario (its error names the run)."""
    seen = set()
    for run in study.runs():
        if run.cell in seen:
            continue
        seen.add(run.cell)
        try:
            load_scenario(study.scenario, run.overrides)
        except ScenarioError as exc:
            raise StudyError(f"run {run.key} ({describe(run.values)}): {exc}") from None


def describe(values: dict) -> str:
    return ", ".join(f"{k}={_short(v)}" for k, v in values.items()) or "the base scenario"


def _short(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return "[" + ", ".join(_short(v) for v in value) + "]"
    return str(value)


# ------------------------------------------------------------------ results
def flatten(data: dict, prefix: str = "") -> dict:
    """Nested dicts -> {dotted key: scalar}; lists and None-only leaves are left out."""
    out = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        elif isinstance(value, (bool, int, float, str)):
            out[name] = value
    return out


# run.json fields that describe the run rather than measure it
_RUN_FIELDS = ("status", "cause", "trip_reason", "error", "wall_s", "sensor_missed_steps", "mode")
_REPORT_LEFT_OUT = ("bag", "namespace", "machine", "machine_source", "kind", "scenario", "run_dir", "plots")


def run_metrics(run: dict, report: dict | None) -> dict:
    """A run's metrics from its run.json content and its report's metrics (None when it
    was not recorded): run.*, controller.*, sim_hw.*, gough_sensor.*, report.*."""
    out = {f"run.{k}": run.get(k) for k in _RUN_FIELDS if k in run}
    out["run.lost_total"] = sum((run.get("lost") or {}).values())
    for node in ("controller", "sim_hw", "gough_sensor"):
        summary = dict((run.get("summaries") or {}).get(node) or {})
        summary.pop("published", None)
        out.update(flatten(summary, f"{node}."))
    if report:
        out.update(flatten({k: v for k, v in report.items() if k not in _REPORT_LEFT_OUT}, "report."))
    return out


def result_row(run: RunSpec, metrics: dict) -> dict:
    """One row of the study's table: the run's key, cell and draw, its varied
    parameters, then its metrics."""
    return {"key": run.key, "index": run.index, "cell": run.cell, "draw": run.draw, **run.values, **metrics}


def failed_metrics(error: str) -> dict:
    return {"run.status": "failed", "run.error": error}
