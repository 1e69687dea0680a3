"""Engine benchmark (issue 45): steps per second of one lockstep run in the direct
engine (pkm_bringup.direct) against the graph, as processes and in one process, in the
same minutes, and the share of each part of a direct cycle.

The run: ``--scenario`` (default archi_demo: ARCHI, its Gough in the loop, sensor-space
control, infinity-norm distribution) for ``--duration-s`` of simulated time, recorded
as the scenario says. Steps per second: the plant's own count over its loop's wall time
(sim_hw's summary, ``steps_per_s``), so that the start-up is left out of every engine.
The engines alternate, ``--repeat`` runs each; printed min / median / max and the ratio
of the medians (target: direct >= 10x the graph as processes).

The shares: one more direct run with every loop's reader timed (perf_counter around
each call): the plant (SimLoop.on_command: its step and the publication), the Gough
sensor, the controller's two halves (on_state: prepare, on_metrology: complete), and
what is left of the wall time: the engine's queue and the recorder's tap.

``--baseline DIR``: also the graph as processes of another checkout's code (the
issue's 143a5f0: "ratios against today's code"), in turn with the others
(baseline.py).

Usage: python benchmarks/engine.py [--scenario archi_demo] [--duration-s 2.0] [--repeat 3] [--baseline DIR]
"""

from __future__ import annotations

import argparse
import collections
import statistics
import sys
import tempfile
import time
from pathlib import Path


ONE_RUN = """
import json, sys
from pathlib import Path
from pkm_bringup.processes import use_ros_environment
use_ros_environment()
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
scenario, duration_s, engine, in_process, run_dir = sys.argv[1], float(sys.argv[2]), *sys.argv[3:6]
in_process = in_process == "1"
s = load_scenario(scenario, {"duration_s": duration_s})
run = run_scenario(s, Path(run_dir), in_process=in_process, progress=False, report=False, engine=engine)
print(json.dumps({"status": run["status"], "error": run.get("error", ""),
                  "steps_per_s": run["summaries"].get(s.machine_node, {}).get("steps_per_s")}))
"""


def one_run(scenario: str, duration_s: float, engine: str, in_process: bool, tmp: Path, index: int) -> float:
    """Steps per second of one run in a process of its own, as ``pkm-run`` runs it (a run in
    the benchmark's process met the threads an earlier in-process graph left behind)."""
    import json
    import subprocess
    run_dir = tmp / f"{engine}-{in_process}-{index}"
    arguments = [scenario, str(duration_s), engine, "1" if in_process else "0", str(run_dir)]
    done = subprocess.run([sys.executable, "-c", ONE_RUN, *arguments], capture_output=True, text=True, timeout=600)
    lines = done.stdout.strip().splitlines()
    failed = {"status": "failed", "error": done.stderr[-2000:]}
    run = json.loads(lines[-1]) if done.returncode == 0 and lines else failed
    if run["status"] != "completed" or run["steps_per_s"] is None:
        raise SystemExit(f"{scenario} ({engine}, in_process={in_process}): {run['status']}: {run['error']}")
    return float(run["steps_per_s"])


def shares(scenario: str, duration_s: float, tmp: Path) -> tuple[dict, float, int]:
    """Seconds per part of a direct run, its loop's wall time and its steps."""
    from pkm_bringup.direct import DirectRun
    from pkm_bringup.graph import Progress
    from pkm_bringup.orchestrator import make_run_dir, run_scenario
    from pkm_bringup.scenario import load_scenario, node_parameters
    from pkm_common.credential import KEY_FILE, RunKey
    from pkm_common.runner import start_up_frozen
    # a short run first: a process's first run loads the compiled kernels and makes its first messages
    one = tmp / "warm-up"
    one.mkdir()
    run_scenario(load_scenario(scenario, {"duration_s": 0.1, "record": False}), one, progress=False, report=False,
                 engine="direct")
    s = load_scenario(scenario, {"duration_s": duration_s})
    run_dir = make_run_dir(s, tmp)
    for sub in ("params", "logs", "summaries"):
        (run_dir / sub).mkdir(parents=True)
    RunKey.create(run_dir / KEY_FILE)
    run = DirectRun(s, run_dir, node_parameters(s, run_dir))
    spent: dict = collections.defaultdict(float)
    names = {"on_command": "plant (SimLoop.on_command)", "on_state": "controller prepare (on_state)",
             "on_metrology": "controller complete (on_metrology)", "on_true_pose": "Gough sensor (on_true_pose)"}

    def timed(reader):
        key = names.get(reader.__name__, reader.__qualname__)

        def call(data):
            start = time.perf_counter()
            reader(data)
            spent[key] += time.perf_counter() - start
        return call
    for topic in run.topics.values():
        topic.readers = [timed(r) for r in topic.readers]
    start = time.perf_counter()
    try:
        with start_up_frozen(collect=False):           # as run_direct runs the loop
            run.run(Progress(duration_s, enabled=False), time.monotonic() + 600)
    finally:
        wall = time.perf_counter() - start
        run.close()
    return dict(spent), wall, run.plant.k


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="archi_demo")
    parser.add_argument("--duration-s", type=float, default=2.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--baseline", type=Path, help="a checkout whose graph as processes is measured too")
    args = parser.parse_args()
    from pkm_bringup.processes import use_ros_environment
    use_ros_environment()
    rates = collections.defaultdict(list)
    engines = (("graph, processes", "graph", False), ("graph, one process", "graph", True), ("direct", "direct", False))
    if args.baseline is not None:
        from baseline import graph_steps_per_s
        baseline = f"graph, processes, {args.baseline.resolve().name}'s code"
        engines = ((baseline, "", False), *engines)
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat):
            for label, engine, in_process in engines:
                rates[label].append(graph_steps_per_s(args.baseline, args.scenario, args.duration_s) if not engine
                                    else one_run(args.scenario, args.duration_s, engine, in_process, Path(tmp), k))
        parts, wall, steps = shares(args.scenario, args.duration_s, Path(tmp))
    print(f"{args.scenario}, {args.duration_s:g} s simulated, {args.repeat} runs per engine, alternating")
    print("| engine | steps/s min | median | max | direct / this (median) |")
    print("|---|---|---|---|---|")
    direct = statistics.median(rates["direct"])
    for label, _, _ in engines:
        r = rates[label]
        print(f"| {label} | {min(r):.0f} | {statistics.median(r):.0f} | {max(r):.0f} | "
              f"{direct / statistics.median(r):.2f} |")
    print(f"\na direct cycle, {steps} steps timed ({steps / wall:.0f} steps/s with the timers): us per step, share")
    print("| part | us/step | share |")
    print("|---|---|---|")
    for part, seconds in sorted(parts.items(), key=lambda kv: -kv[1]):
        print(f"| {part} | {seconds / steps * 1e6:.1f} | {seconds / wall * 100:.0f} % |")
    rest = wall - sum(parts.values())
    print(f"| the engine: queue, dispatch, recording tap | {rest / steps * 1e6:.1f} | {rest / wall * 100:.0f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
