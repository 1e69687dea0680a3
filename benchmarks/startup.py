"""Start-up benchmark (issue 45's "start-up in seconds"): how long a user waits.

1. ``pkm-run --help``: the console script's wall time (its arguments are read before
   the orchestrator is imported: pkm_bringup.run_cli).
2. From starting a run to its first simulated step: a fresh interpreter runs
   ``--scenario`` (shortened to ``--duration-s``, not recorded) as processes and in one
   process (as pkm-run: the node server started first, processes.start_node_server); the
   first step is the time sim_hw logs "loop started" (the ROS log's wall clock), against
   the wall clock just before the interpreter was started. Printed:
   min / median / max over ``--repeat`` runs of each.

Usage: python benchmarks/startup.py [--repeat 3] [--scenario archi_demo] [--duration-s 0.3]
       [--modes processes,in-process]
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOOP_STARTED = re.compile(r"\[(\d+\.\d+)\] \[pkm\.(?:sim_hw|drives|ros2_control)\]: loop started")

_RUN = """
import sys
if sys.argv[4] == "processes":       # as pkm-run does (run_cli.main), first
    from pkm_bringup.processes import start_node_server, use_ros_environment
    use_ros_environment()
    start_node_server()
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.processes import use_ros_environment
from pkm_bringup.scenario import load_scenario
use_ros_environment()
s = load_scenario(sys.argv[1], {"duration_s": float(sys.argv[2]), "record": False})
from pathlib import Path
run = run_scenario(s, Path(sys.argv[3]), in_process=sys.argv[4] == "in-process", progress=False, report=False)
sys.exit(0 if run["status"] == "completed" else 1)
"""


def help_seconds() -> float:
    script = Path(sys.executable).with_name("pkm-run")
    start = time.perf_counter()
    subprocess.run([str(script), "--help"], check=True, capture_output=True)
    return time.perf_counter() - start


def first_step_seconds(scenario: str, duration_s: float, mode: str) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "run"
        start = time.time()
        out = subprocess.run([sys.executable, "-c", _RUN, scenario, str(duration_s), str(run_dir), mode], cwd=ROOT,
                             capture_output=True, text=True, timeout=300)
        text = out.stdout + out.stderr + "".join(p.read_text() for p in (run_dir / "logs").glob("*.log"))
        if out.returncode != 0:
            raise SystemExit(f"{scenario} ({mode}) did not complete:\n{text[-3000:]}")
        found = LOOP_STARTED.search(text)
        if not found:
            raise SystemExit(f"{scenario} ({mode}): no 'loop started' in its logs:\n{text[-3000:]}")
        return float(found.group(1)) - start


def row(name: str, values: list[float]) -> str:
    return f"| {name} | {min(values):.2f} | {statistics.median(values):.2f} | {max(values):.2f} |"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--scenario", default="archi_demo")
    p.add_argument("--duration-s", type=float, default=0.3)
    p.add_argument("--modes", default="processes,in-process")
    args = p.parse_args(argv)
    print("| what (s) | min | median | max |")
    print("|---|---|---|---|")
    print(row("pkm-run --help", [help_seconds() for _ in range(args.repeat)]), flush=True)
    for mode in args.modes.split(","):
        print(row(f"{args.scenario}: start to the first simulated step, {mode}",
                  [first_step_seconds(args.scenario, args.duration_s, mode) for _ in range(args.repeat)]), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
