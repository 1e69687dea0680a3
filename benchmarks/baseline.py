"""An older checkout's code measured in the same minutes as this one (benchmarks'
``--baseline DIR``): issue 45's targets are ratios "against today's code in the same
minutes", today being the commit the issue was measured on (143a5f0), and this VM's
speed drifts by +-20 % between runs and days, so a figure from the issue's day is not
a baseline.

``DIR`` is a checkout (``git worktree add /tmp/base 143a5f0``). Its code runs in a
child process of this venv with its own ``src/*`` packages first on ``PYTHONPATH``
(the package directories shadow this checkout's installed ones), from its own
directory (its ``config/``); the child prints one JSON line, which is returned.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


def baseline_env(checkout: Path) -> dict:
    """The environment that imports ``checkout``'s packages before this venv's."""
    src = sorted(str(p) for p in (Path(checkout).resolve() / "src").iterdir() if p.is_dir())
    if not src:
        raise SystemExit(f"--baseline {checkout}: no packages under src/ (a checkout of this repository?)")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([*src, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def run_baseline(checkout: Path, code: str, timeout_s: float = 900.0) -> dict:
    """``code`` (it prints one JSON object last) run with ``checkout``'s code; its result.
    The child says where it imported ``pkm_bringup`` from: a run of this checkout's code
    (an editable install's finder answering where the baseline has no such package)
    is refused, not reported as the baseline's."""
    checkout = Path(checkout).resolve()
    done = subprocess.run([sys.executable, "-c", "import pkm_bringup; print(pkm_bringup.__file__)\n" + code],
                          cwd=checkout, env=baseline_env(checkout), capture_output=True, text=True,
                          timeout=timeout_s, check=False)
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or len(lines) < 2:
        raise SystemExit(f"--baseline {checkout}: the child failed ({done.returncode}):\n{done.stderr[-2000:]}")
    if not Path(lines[0]).resolve().is_relative_to(checkout):
        raise SystemExit(f"--baseline {checkout}: the child imported pkm_bringup from {lines[0]}, not the checkout")
    return json.loads(lines[-1])


GRAPH_RUN = """
import json, tempfile
from pathlib import Path
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
s = load_scenario({scenario!r}, {{"duration_s": {duration_s!r}}})
with tempfile.TemporaryDirectory() as tmp:
    run = run_scenario(s, Path(tmp) / "run", in_process=False, progress=False, report=False)
node = getattr(s, "machine_node", "sim_hw")
print(json.dumps({{"status": run["status"], "error": run.get("error"),
                  "steps_per_s": run["summaries"].get(node, {{}}).get("steps_per_s")}}))
"""


def graph_steps_per_s(checkout: Path, scenario: str, duration_s: float) -> float:
    """Steps per second of one lockstep run as processes with ``checkout``'s code."""
    out = run_baseline(checkout, GRAPH_RUN.format(scenario=scenario, duration_s=duration_s))
    if out["status"] != "completed" or out["steps_per_s"] is None:
        raise SystemExit(f"--baseline {checkout}: {scenario}: {out['status']}: {out['error']}")
    return float(out["steps_per_s"])


STUDY_RUNS = """
import importlib.util, json
spec = importlib.util.spec_from_file_location("baseline_study_benchmark", "benchmarks/study.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)
out = bench.closed_loop(1, {runs!r}, {duration_s!r})
print(json.dumps({{key: out[key] for key in ("per_hour", "task_s", "failed", "runs")}}))
"""


def study_runs_per_hour(checkout: Path, runs: int, duration_s: float) -> dict:
    """``checkout``'s own study benchmark (its ``benchmarks/study.py`` closed_loop, one
    worker): runs per hour, the median run's time, runs and failed runs."""
    return run_baseline(checkout, STUDY_RUNS.format(runs=runs, duration_s=duration_s))
