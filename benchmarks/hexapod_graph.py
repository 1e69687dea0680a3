"""The hexapod graph against the ARCHI graph: lockstep rate of the whole graph (sim_hw,
controller, planner, recorder; as processes) on a 6-DOF machine against a 3-DOF one
in the same minutes (issue 23's target: the hexapod at >= 80 % of ARCHI's rate).

Both run the same control: computed torque on the encoders, pseudo-inverse
distribution, no Gough metrology, recorded: ``hexapod_demo`` (genhexkins, 6 struts,
a 6-DOF program) and ``archi_demo`` with those settings (ARCHI, 4 drives, its test
motion). Runs alternate (hexapod, ARCHI, hexapod, ...) so that a slow phase of this VM
falls on both; printed per pair the sim_hw steps per wall second of each and their
ratio, then the median ratio. Also the controller's compute p50 of each run (its own
summary: the cycle's CPU work, the part of the rate that the 6-DOF model adds).

Usage: python benchmarks/hexapod_graph.py [--pairs 3] [--duration-s 3] [--in-process]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

CONTROL = {"strategy": "computed_torque", "distribution": "pseudo_inverse"}


def run_once(scenario: str, duration_s: float, in_process: bool) -> tuple[float, float, str]:
    """(steps per wall second, controller compute p50 in us, status) of one run."""
    from pkm_bringup.orchestrator import run_scenario
    from pkm_bringup.scenario import load_scenario
    overrides = {"metrology": False, "controller": CONTROL, "record": True, "duration_s": duration_s}
    s = load_scenario(scenario, overrides)
    with tempfile.TemporaryDirectory() as tmp:
        run = run_scenario(s, Path(tmp) / "run", in_process=in_process, progress=False, report=False)
    if run["status"] == "failed":
        raise RuntimeError(f"{scenario}: run failed: {run['error']}")
    sim, ctl = run["summaries"]["sim_hw"], run["summaries"].get("controller", {})
    return float(sim["steps_per_s"]), float(ctl.get("compute_us_p50", float("nan"))), run["status"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--duration-s", type=float, default=3.0, help="simulated time of each run")
    parser.add_argument("--in-process", action="store_true", help="the graph in one process")
    args = parser.parse_args(argv)
    mode = "in one process" if args.in_process else "as processes"
    print(f"lockstep graph {mode}, computed torque, pseudo-inverse, recorded, {args.duration_s:g} s simulated")
    print(f"{'pair':>4}  {'hexapod steps/s':>15}  {'ARCHI steps/s':>13}  {'ratio':>6}  "
          f"{'compute p50 us (hexapod, ARCHI)':>32}")
    ratios = []
    for k in range(args.pairs):
        hexapod = run_once("hexapod_demo", args.duration_s, args.in_process)
        archi = run_once("archi_demo", args.duration_s, args.in_process)
        ratios.append(hexapod[0] / archi[0])
        status = "" if hexapod[2] == archi[2] == "completed" else f"  ({hexapod[2]}, {archi[2]})"
        print(f"{k + 1:>4}  {hexapod[0]:>15.0f}  {archi[0]:>13.0f}  {ratios[-1]:>6.2f}  "
              f"{hexapod[1]:>15.0f}, {archi[1]:<15.0f}{status}")
    print(f"median ratio hexapod / ARCHI: {statistics.median(ratios):.2f} (target >= 0.80)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
