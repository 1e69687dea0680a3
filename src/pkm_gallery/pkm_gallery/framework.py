"""The gallery's framework: an :class:`Experiment` names its paper and section and the
scenarios it runs; its ``run`` takes a :class:`Bench` (where runs and figures go) and
returns an :class:`Outcome`: the checks (the paper's claim, our measured figure, a
verdict), a table of the measured figures and the figures drawn. Also here: what
several papers' experiments measure on a run (its per-step arrays, the internal
force, the tracking error) and the figure helper. The experiments, one module per
paper, are registered in :mod:`pkm_gallery.experiments`.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pkm_bringup.direct import refusal as direct_refusal
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_runs.report_data import load_run, rpy_of, yaw_of
from pkm_runs.report_metrics import internal_force_rows

PAPERS = {   # the references of README.md (References), by their short names
    "ARCHI": 'F. Marquet, S. Krut, O. Company, F. Pierrot, "ARCHI: a redundant mechanism for machining '
             'with unlimited rotation capacities", ICAR 2001, Budapest.',
    "MoM3": 'D. Corbel, O. Company, S. Krut, F. Pierrot, "Enhancing PKM accuracy by separating actuation '
            'and measurement: a 3DOF case study", ASME J. Mechanisms and Robotics 2(3), 031008, 2010.',
    "Sliding Star": 'M. Valasek, Z. Sika, J. Zavrel, T. Skopec, P. Steinbauer, "Control rapid prototyping '
                    'of redundantly actuated parallel kinematical machine".',
    "Orthoglide": 'P. Wenger, D. Chablat, "Design of a three-axis isotropic parallel manipulator for '
                  'machining applications: the Orthoglide", Workshop on Fundamental Issues and Future '
                  'Research Directions for Parallel Mechanisms and Manipulators, Quebec, 2002.',
    "LinuxCNC": 'LinuxCNC, genhexkins: kinematics of the Gough-Stewart platform (src/emc/kinematics/'
                'genhexkins.c, genhexkins.h), its default geometry (config/machines/genhexkins.yaml).',
}


@dataclass(frozen=True)
class Check:
    """One criterion: what the paper claims (with our threshold), what we measured."""
    claim: str
    measured: str
    passed: bool


@dataclass
class Outcome:
    """What an experiment found: its checks, a table of measured figures (header row
    first) and the figure files drawn (names in the bench's figure directory)."""
    checks: list[Check] = field(default_factory=list)
    table: list[list[str]] = field(default_factory=list)
    figures: list[str] = field(default_factory=list)
    notes: str = ""

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    def check(self, claim: str, measured: str, passed) -> bool:
        self.checks.append(Check(claim, measured, bool(passed)))
        return bool(passed)


@dataclass(frozen=True)
class Experiment:
    """A paper's experiment: ``run(bench) -> Outcome``."""
    name: str
    title: str
    paper: str                     # a key of PAPERS
    section: str                   # where in the paper (section, figure, table)
    scenarios: tuple[str, ...]     # the scenario files it runs (config/scenarios/<name>.yaml)
    run: object                    # callable(Bench) -> Outcome

    def __post_init__(self):
        if self.paper not in PAPERS:
            raise FieldError("paper", f"must be one of {list(PAPERS)}, got {self.paper!r}")


@dataclass
class Bench:
    """Where an experiment's runs (``work``) and figures (``figures``) go."""
    work: Path
    figures: Path
    progress: bool = False

    def run(self, scenario: str, label: str = "", **overrides) -> RunOutput:
        """Run a scenario in one process (``overrides`` replace its top-level keys): in
        the direct engine where it can (the graph's run bit for bit, pkm_bringup.direct),
        else as a graph in one executor; its run.json content and its per-step arrays."""
        run_dir = self.work / (label or scenario)
        shutil.rmtree(run_dir, ignore_errors=True)     # the gallery's own: a run again starts afresh
        s = load_scenario(scenario, overrides or None)
        run = run_scenario(s, run_dir, in_process=True, progress=self.progress, report=False,
                           engine="graph" if direct_refusal(s) else "direct")
        if run["status"] == "failed":
            raise RuntimeError(f"{scenario} ({label or 'as shipped'}): the run failed: {run['error']}")
        return RunOutput(run, step_arrays(run_dir))

    def figure(self, name: str) -> Path:
        self.figures.mkdir(parents=True, exist_ok=True)
        return self.figures / name


@dataclass
class RunOutput:
    run: dict                      # run.json
    steps: dict                    # step_arrays()

    @property
    def status(self) -> str:
        return self.run["status"]

    @property
    def cause(self) -> str:
        return self.run.get("cause") or "none"


def step_arrays(run_dir: Path) -> dict:
    """The per-step streams of a recorded run as arrays over the drive-state stamps:
    ``t_s`` (from the first state), ``q``, ``applied`` (N, n); ``command`` (N, n);
    ``position`` (N, 3), ``yaw`` (N,) and ``orientation`` (N, 4: x, y, z, w) of the true
    pose, ``ref_position`` ... of the controller's reference, ``gough_position`` ... of
    the Gough metrology's DKM pose (NaN where a stream has no message of the stamp).
    A gallery run is a few thousand steps: held whole (report_data.load_run, the one
    in-memory view of a run)."""
    steps = load_run(run_dir).steps
    state = steps.rows.get("state")
    if state is None:
        empty = {k: np.zeros(0) for k in ("t_s", "q", "applied", "command")}
        for prefix in ("", "ref_", "gough_"):
            empty.update({prefix + "position": np.zeros(0), prefix + "yaw": np.zeros(0),
                          prefix + "orientation": np.zeros(0)})
        return empty
    keep = state.present
    stamp = steps.stamp_ns[keep]
    command = steps.rows.get("command")
    out = {"t_s": (stamp - stamp[0]) * 1e-9 if len(stamp) else np.zeros(0), "q": state.position[keep],
           "applied": state.effort[keep],
           "command": command.effort[keep] if command is not None else np.full_like(state.effort[keep], np.nan)}
    for key, prefix in (("true_pose", ""), ("reference", "ref_"), ("metrology_pose", "gough_")):
        pose = steps.rows.get(key)
        if pose is not None:
            position, orientation = pose.position[keep], pose.orientation[keep].copy()
            orientation[~pose.present[keep]] = np.nan
        else:
            position, orientation = np.full((len(stamp), 3), np.nan), np.full((len(stamp), 4), np.nan)
        out[prefix + "position"], out[prefix + "yaw"], out[prefix + "orientation"] = \
            position, yaw_of(orientation), orientation
    return out


# ------------------------------------------------------------------ results.md


def plot(bench: Bench, name: str, draw, size=(8, 4.5)) -> str:
    """Draw a figure with ``draw(fig)`` (matplotlib's Agg canvas) into the bench's
    figure directory; returns its file name."""
    fig = Figure(figsize=size, dpi=100)
    FigureCanvasAgg(fig)
    draw(fig)
    fig.tight_layout()
    fig.savefig(bench.figure(name))
    return name


def internal_force(out: RunOutput, machine: str = "archi") -> np.ndarray:
    """||f_int|| per step of the applied forces, f_int = f - J (J^T J)^-1 J^T f at the
    true pose of a planar machine (x, y, yaw) or a spatial one (x, y, z, a, b, c) (the
    report's definition, pkm_runs.report_metrics)."""
    s, cfg = out.steps, load_machine(machine)
    if cfg.model.task_space.dof == 6:
        poses = np.column_stack([s["position"], rpy_of(s["orientation"])])
    else:
        poses = np.column_stack([s["position"][:, 0], s["position"][:, 1], s["yaw"]])
    return internal_force_rows(cfg, s["applied"], poses)


def tracking_error_m(out: RunOutput) -> np.ndarray:
    """|p_true - p_ref| (x, y) per step."""
    s = out.steps
    return np.hypot(*(s["position"][:, :2] - s["ref_position"][:, :2]).T)
