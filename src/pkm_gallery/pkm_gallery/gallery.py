"""``pkm-gallery``: the papers' experiments, each run from its scenario file, checked
against what the paper claims, and written to ``docs/results.md`` with its figures.

An :class:`Experiment` (the registry: :mod:`pkm_gallery.experiments`) names its paper
and section and the scenarios it runs; its ``run`` takes a :class:`Bench` (where runs
and figures go) and returns an :class:`Outcome`: the checks (the paper's claim, our
measured figure, a verdict), a table of the measured figures and the figures drawn.
The gallery runs the scenarios in one process (``pkm-run --in-process``: the same
nodes in one executor, faster than a graph of processes); ``pkm-run <scenario>``
runs any of them alone. The same ``run`` is what each experiment's test calls, so the
test and ``docs/results.md`` judge the same numbers.

Exit status: 0 when every check passed, 1 when one failed (results.md says which),
2 for an unknown experiment name.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

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
            raise ValueError(f"paper: must be one of {list(PAPERS)}, got {self.paper!r}")


@dataclass
class Bench:
    """Where an experiment's runs (``work``) and figures (``figures``) go."""
    work: Path
    figures: Path
    progress: bool = False

    def run(self, scenario: str, label: str = "", **overrides) -> RunOutput:
        """Run a scenario in one process (``overrides`` replace its top-level keys);
        its run.json content and its per-step arrays."""
        from pkm_bringup.orchestrator import run_scenario
        from pkm_bringup.scenario import load_scenario
        run_dir = self.work / (label or scenario)
        shutil.rmtree(run_dir, ignore_errors=True)     # the gallery's own: a run again starts afresh
        run = run_scenario(load_scenario(scenario, overrides or None), run_dir, in_process=True,
                           progress=self.progress, report=False)
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
    A gallery run is a few thousand steps: held whole."""
    from pkm_runs.report_data import RunReader, yaw_of
    parts: dict = {k: [] for k in ("stamp", "q", "applied", "command", "position", "yaw", "orientation",
                                   "ref_position", "ref_yaw", "ref_orientation", "gough_position", "gough_yaw",
                                   "gough_orientation")}
    with RunReader(run_dir) as reader:
        for block in reader.blocks():
            state = block.rows.get("state")
            if state is None:
                continue
            keep = state.present
            parts["stamp"].append(block.stamp_ns[keep])
            parts["q"].append(state.position[keep])
            parts["applied"].append(state.effort[keep])
            command = block.rows.get("command")
            parts["command"].append(command.effort[keep] if command is not None
                                    else np.full_like(state.effort[keep], np.nan))
            for key, prefix in (("true_pose", ""), ("reference", "ref_"), ("metrology_pose", "gough_")):
                pose = block.rows.get(key)
                if pose is not None:
                    position, orientation = pose.position[keep], pose.orientation[keep].copy()
                    orientation[~pose.present[keep]] = np.nan
                else:
                    position, orientation = np.full((int(keep.sum()), 3), np.nan), np.full((int(keep.sum()), 4), np.nan)
                parts[prefix + "position"].append(position)
                parts[prefix + "yaw"].append(yaw_of(orientation))
                parts[prefix + "orientation"].append(orientation)
    out = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    stamp = out.pop("stamp")
    out["t_s"] = (stamp - stamp[0]) * 1e-9 if len(stamp) else np.zeros(0)
    return out


# ------------------------------------------------------------------ results.md
def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def markdown_table(rows: list[list]) -> str:
    if not rows:
        return ""
    lines = ["| " + " | ".join(_cell(c) for c in rows[0]) + " |",
             "|" + "---|" * len(rows[0])]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows[1:]]
    return "\n".join(lines)


def results_markdown(results: list[tuple[Experiment, Outcome, float]], figure_prefix: str = "figures",
                     pending=()) -> str:
    """docs/results.md: the summary table, then per experiment the paper's claims,
    ours and the verdicts, the measured table and the figures; ``pending``: (name,
    where in the paper, why not here) of the experiments not run yet."""
    out = ["# Results: the papers' experiments on the simulated machines", "",
           "Written by `pkm-gallery` (`pkm_gallery.gallery`) from the runs of each experiment's",
           "scenarios (`config/scenarios/`, each runs alone with `pkm-run <name>`); every check below is",
           "asserted by the experiment's test in `make test` on the same numbers. Do not edit by hand:",
           "run `pkm-gallery` again.", "",
           "| experiment | paper | checks | verdict |", "|---|---|---|---|"]
    for exp, outcome, _ in results:
        passed = sum(c.passed for c in outcome.checks)
        verdict = "reproduced" if outcome.passed else "NOT reproduced"
        out.append(f"| [{exp.name}](#{exp.name}) | {exp.paper} {exp.section} | {passed} / "
                   f"{len(outcome.checks)} | {verdict} |")
    if pending:
        out += ["", "Not reproduced here yet:", ""] + [f"- `{name}` ({where}): {why}" for name, where, why in pending]
    out += ["", "## References", ""] + [f"- **{k}**: {v}" for k, v in PAPERS.items()]
    for exp, outcome, seconds in results:
        runs = ("scenarios: " + ", ".join(f"`{s}`" for s in exp.scenarios)) if exp.scenarios else "no run"
        out += ["", f"## {exp.name}", "", f"**{exp.title}** ({exp.paper} {exp.section}; {runs}; "
                f"{seconds:.0f} s here)", ""]
        out += [markdown_table([["the paper (our criterion)", "measured", "verdict"]]
                               + [[c.claim, c.measured, "pass" if c.passed else "FAIL"] for c in outcome.checks])]
        if outcome.table:
            out += ["", markdown_table(outcome.table)]
        if outcome.notes:
            out += ["", outcome.notes.strip()]
        out += [""] + [f"![{f}]({figure_prefix}/{f})" for f in outcome.figures]
    return "\n".join(out).rstrip() + "\n"


# ------------------------------------------------------------------ command line
def main(argv=None) -> int:
    from pkm_gallery.experiments import EXPERIMENTS, PENDING
    parser = argparse.ArgumentParser(prog="pkm-gallery", description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help=f"experiments (default: all): {', '.join(EXPERIMENTS)}")
    parser.add_argument("--docs", default="docs", help="where results.md and figures/ are written (default: docs)")
    parser.add_argument("--work", default="", help="keep the runs here (default: a temporary directory)")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in EXPERIMENTS]
    if unknown:
        print(f"pkm-gallery: unknown experiment(s) {unknown}; known: {list(EXPERIMENTS)}", file=sys.stderr)
        return 2
    import tempfile

    import rclpy.logging
    # the nodes run in this process: their INFO lines (configured, run complete...) would
    # bury the table; warnings and errors still show (a node's logger inherits "pkm"'s)
    rclpy.logging.set_logger_level("pkm", rclpy.logging.LoggingSeverity.WARN)
    docs = Path(args.docs)
    results = []
    with tempfile.TemporaryDirectory(prefix="pkm-gallery-") as tmp:
        work = Path(args.work) if args.work else Path(tmp)
        for name in args.names or list(EXPERIMENTS):
            exp = EXPERIMENTS[name]
            start = time.monotonic()
            outcome = exp.run(Bench(work / name, docs / "figures"))
            seconds = time.monotonic() - start
            results.append((exp, outcome, seconds))
            print(f"{name:28s} {'reproduced' if outcome.passed else 'NOT reproduced':15s} "
                  f"{sum(c.passed for c in outcome.checks)} / {len(outcome.checks)} checks  {seconds:5.1f} s")
            for c in outcome.checks:
                if not c.passed:
                    print(f"    FAIL: {c.claim}: {c.measured}")
    if len(results) == len(EXPERIMENTS):
        docs.mkdir(parents=True, exist_ok=True)
        (docs / "results.md").write_text(results_markdown(results, pending=PENDING), encoding="utf-8")
        print(f"written: {docs / 'results.md'}")
    else:                          # results.md holds every experiment or none
        print(f"{docs / 'results.md'} not written (a subset ran); figures in {docs / 'figures'}")
    return 0 if all(o.passed for _, o, _ in results) else 1


if __name__ == "__main__":
    sys.exit(main())
