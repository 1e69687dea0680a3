"""Controller benchmarks (issue 5).

    .venv/bin/python benchmarks/controller.py [--cycles 3000] [--graph-duration 3]

1. Per-cycle compute time of ``ControllerCore.update`` for every strategy and
   distribution (median, p99), timed inside a core closed loop against the plant
   (only the controller's calls are timed): ARCHI (with its Gough metrology) and
   MoM3. The cycle is ``prepare`` (on the drive state) + ``complete`` (on the
   metrology); ``complete`` alone is what separates the readings from the command
   in the graph, where ``prepare`` runs while the readings are on their way.
   Target: <= 200 us p99 with the inf-norm distribution.
2. The closed-loop lockstep rate of the full graph, each node its own process:
   controller (sensor_space) + sim_hw + gough_sensor (+ trajectory_node, idle after
   publishing) on MoM3. Target: >= 1,000 cycles/s, and how far from 2,000 (MoM3).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pkm_bringup.processes import ros_environment
from pkm_common.timing import percentiles_us
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.reference import Reference
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_sim_hw.plant import Plant, PlantParameters

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hoststat import CpuSteal  # noqa: E402  (benchmarks/hoststat.py)
from plant import start, stop_all  # noqa: E402  (benchmarks/plant.py: process helpers)

ROOT = Path(__file__).resolve().parents[1]


class TimedCore(ControllerCore):
    """ControllerCore whose two halves are timed (perf_counter around each call):
    ``update`` = ``prepare`` (drive state) + ``complete`` (metrology)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.prepare_s: list[float] = []
        self.complete_s: list[float] = []

    def prepare(self, *args, **kwargs):
        start = time.perf_counter()
        out = super().prepare(*args, **kwargs)
        self.prepare_s.append(time.perf_counter() - start)
        return out

    def complete(self, *args, **kwargs):
        start = time.perf_counter()
        out = super().complete(*args, **kwargs)
        self.complete_s.append(time.perf_counter() - start)
        return out


def compute_times(machine_name: str, strategy: str, distribution: str, cycles: int) -> tuple:
    """(p50, p99) of the whole cycle and (p50, p99) of ``complete`` alone (what lies
    between the metrology readings and the command in the graph), us."""
    machine = load_machine(machine_name)
    home = machine.model.home.tolist()
    target = list(home)
    target[0] += 0.01
    ref = Reference([0.0, 0.5], [home, target], [[0.02, 0.0, 0.0]] * 2)     # a slow ramp: work every cycle
    core = TimedCore(machine, ControllerConfig(strategy=strategy, distribution=distribution,
                                               following_error_m=0.05))
    sensor = GoughSensorModel(machine.metrology) if machine.metrology is not None else None
    run(machine, core, Plant(machine, PlantParameters()), cycles, reference=ref, sensor=sensor)
    if core.stopped:
        raise RuntimeError(f"{strategy}/{distribution} stopped: {core.stop_reason}")
    prepare, complete = np.array(core.prepare_s[10:]), np.array(core.complete_s[10:])
    cycle, after = percentiles_us("cycle", prepare + complete), percentiles_us("complete", complete)
    return cycle["cycle_us_p50"], cycle["cycle_us_p99"], after["complete_us_p50"], after["complete_us_p99"]


def graph_rate(duration_s: float) -> dict:
    env = ros_environment(own_domain=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        procs = [start("pkm_gough_sensor.gough_sensor_node", {"machine": "mom3"}, env, tmp / "sensor.log"),
                 start("pkm_controller.controller_node", {"machine": "mom3", "strategy": "sensor_space",
                                                           "summary_path": tmp / "ctrl.json",
                                                           "state_timeout_s": 10.0}, env, tmp / "ctrl.log"),
                 start("pkm_trajectory.trajectory_node", {"machine": "mom3", "program_file":
                                                          ROOT / "config" / "programs" / "mom3_square.nc"},
                       env, tmp / "traj.log")]
        time.sleep(2.0)
        sim = start("pkm_sim_hw.sim_hw_node", {"machine": "mom3", "duration_s": duration_s,
                                               "summary_path": tmp / "sim.json", "publish_markers": "false",
                                               "command_timeout_s": 10.0}, env, tmp / "sim.log")
        try:
            with CpuSteal() as steal:
                sim.wait(timeout=120 + 10 * duration_s)
        finally:
            stop_all(procs + [sim])
        sim_summary = json.loads((tmp / "sim.json").read_text())
        ctrl = json.loads((tmp / "ctrl.json").read_text())
        return {"steps_per_s": sim_summary["steps_per_s"], "stopped": ctrl["stopped"],
                "compute_us_p50": ctrl["compute_us_p50"], "compute_us_p99": ctrl["compute_us_p99"],
                "response_us_p50": ctrl["response_us_p50"], "response_us_p99": ctrl["response_us_p99"],
                "max_tracking_error_m": ctrl["max_tracking_error_m"], "steal": str(steal)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cycles", type=int, default=3000)
    parser.add_argument("--graph-duration", type=float, default=3.0)
    parser.add_argument("--skip-graph", action="store_true")
    args = parser.parse_args(argv)
    rows = [("archi", s, d) for s in ("joint_pid", "decentralized_projected") for d in ("-",)]
    rows += [("archi", s, d) for s in ("cartesian_pid", "computed_torque")
             for d in ("pseudo_inverse", "inf_norm", "p_norm", "two_arm")]
    rows += [("archi", s, d) for s in ("sensor_space", "measured_space") for d in ("pseudo_inverse", "inf_norm")]
    rows += [("mom3", s, "pseudo_inverse") for s in ("computed_torque", "sensor_space", "measured_space")]
    print("| machine | strategy | distribution | cycle p50 (us) | cycle p99 (us) | complete p50 (us) "
          "| complete p99 (us) |\n|---|---|---|---|---|---|---|")
    for machine, strategy, dist in rows:
        p50, p99, c50, c99 = compute_times(machine, strategy, "pseudo_inverse" if dist == "-" else dist,
                                           args.cycles)
        print(f"| {machine} | {strategy} | {dist} | {p50:.1f} | {p99:.1f} | {c50:.1f} | {c99:.1f} |", flush=True)
    if not args.skip_graph:
        g = graph_rate(args.graph_duration)
        print(f"\nfull graph, 4 processes (MoM3 sensor_space + sim_hw + gough_sensor + trajectory): "
              f"{g['steps_per_s']:.0f} cycles/s ({g['steps_per_s'] / 2000:.0%} of 2,000); controller compute "
              f"in the graph p50 {g['compute_us_p50']:.0f} us, p99 {g['compute_us_p99']:.0f} us, from the "
              f"last input to the command p50 {g['response_us_p50']:.0f} us, p99 {g['response_us_p99']:.0f} us; "
              f"stopped: {g['stopped']}; max tracking error {g['max_tracking_error_m'] * 1e6:.1f} um; "
              f"CPU steal by the hypervisor during the run: {g['steal']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
