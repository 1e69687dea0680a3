"""Lockstep exchange rate of the simulated machine with a minimal controller, each in
its own process over DDS, without and with the Gough sensor in the loop.

    .venv/bin/python benchmarks/plant.py [--machine mom3] [--duration 5]

sim_hw_node runs ``--duration`` seconds of simulated time at dt = 1 ms as fast as the
exchange allows and reports steps per wall second; hold_controller_node answers every
state (and, with the sensor, waits for ``metrology/pose`` of the same stamp) and
reports the wall time from a state's arrival to its answer: the sensor's added
latency is the difference of the two runs. Targets (issue 3): >= 3,000 steps/s
without the sensor, >= 2,000 with it. The first row is the floor: a zero-work
two-process ping-pong of the same message type, QoS and executor
(benchmarks/lockstep_echo.py). Each run gets its own ROS_DOMAIN_ID, claimed for this
process (pkm_common.domains): never the domain of a test worker or of another graph.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from pkm_common.files import summary_written
from pkm_bringup.processes import ros_environment
from pkm_kinematics import load_machine


def start(module: str, params: dict, env: dict, log: Path) -> subprocess.Popen:
    args = [sys.executable, "-m", module, "--ros-args", "-r", "__ns:=/pkm"]
    for key, value in params.items():
        args += ["-p", f"{key}:={value}"]
    return subprocess.Popen(args, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)


def stop_all(procs) -> None:
    """SIGINT every live process, wait, kill what does not exit: no orphans."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()


def run(machine: str, with_sensor: bool, duration_s: float) -> dict:
    env = ros_environment(own_domain=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        procs = []
        if with_sensor:
            procs.append(start("pkm_gough_sensor.gough_sensor_node", {"machine": machine}, env, tmp / "sensor.log"))
        procs.append(start("pkm_sim_hw.hold_controller_node",
                           {"machine": machine, "wait_for_metrology": str(with_sensor).lower(),
                            "summary_path": tmp / "ctrl.json"}, env, tmp / "ctrl.log"))
        sim = start("pkm_sim_hw.sim_hw_node",
                    {"machine": machine, "duration_s": duration_s, "summary_path": tmp / "sim.json",
                     "publish_markers": "false", "command_timeout_s": 10.0}, env, tmp / "sim.log")
        try:
            sim.wait(timeout=120 + 10 * duration_s)
        finally:
            stop_all(procs + [sim])
        if not (tmp / "sim.json").exists():
            raise RuntimeError("sim_hw did not finish:\n" + (tmp / "sim.log").read_text()[-2000:])
        sim_summary = json.loads((tmp / "sim.json").read_text())
        ctrl_summary = json.loads((tmp / "ctrl.json").read_text()) if summary_written(tmp / "ctrl.json") else {}
    return {"sim": sim_summary, "ctrl": ctrl_summary}


def echo_floor(steps: int = 6000) -> float | None:
    """steps/s of the zero-work two-process ping-pong (benchmarks/lockstep_echo.py)."""
    env = ros_environment(own_domain=True)
    script = str(Path(__file__).with_name("lockstep_echo.py"))
    answer = subprocess.Popen([sys.executable, script, "answer"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        out = subprocess.run([sys.executable, script, "lead", str(steps)], env=env, capture_output=True,
                             text=True, timeout=120).stdout
    finally:
        answer.send_signal(signal.SIGINT)
        answer.wait(timeout=10)
    rates = [float(line.split()[1]) for line in out.splitlines() if line.startswith("steps/s")]
    return rates[0] if rates else None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--machine", default="mom3")
    parser.add_argument("--duration", type=float, default=5.0, help="simulated seconds per run")
    args = parser.parse_args(argv)
    floor = echo_floor()
    plain = run(args.machine, False, args.duration)
    # a machine without a Gough metrology (the hexapods) has no sensor to run
    sensed = run(args.machine, True, args.duration) if load_machine(args.machine).metrology else None
    rows = [
        ("zero-work echo, 2 processes (floor of this machine)", floor, "steps/s", "-"),
        ("lockstep sim_hw <-> controller (2 processes)", plain["sim"]["steps_per_s"], "steps/s", ">= 3,000"),
        ("state -> answer, no sensor, p50", plain["ctrl"].get("latency_us_p50"), "us", "-"),
        ("state -> answer, no sensor, p99", plain["ctrl"].get("latency_us_p99"), "us", "-"),
    ]
    if sensed is not None:
        rows[2:2] = [("lockstep with the Gough sensor (3 processes)", sensed["sim"]["steps_per_s"], "steps/s",
                      ">= 2,000")]
        rows += [("state -> answer with sensor, p50", sensed["ctrl"].get("latency_us_p50"), "us", "-"),
                 ("state -> answer with sensor, p99", sensed["ctrl"].get("latency_us_p99"), "us", "-")]
    if plain["ctrl"] and sensed is not None and sensed["ctrl"]:
        rows.append(("sensor's added latency, p50", sensed["ctrl"]["latency_us_p50"]
                     - plain["ctrl"]["latency_us_p50"], "us", "-"))
        rows.append(("sensor's added latency, p99", sensed["ctrl"]["latency_us_p99"]
                     - plain["ctrl"]["latency_us_p99"], "us", "-"))
    width = max(len(r[0]) for r in rows)
    print(f"machine {args.machine}, {args.duration} s simulated at dt = 1 ms per run")
    print(f"{'benchmark'.ljust(width)}  {'value':>10}  {'unit':<8}  target")
    print("-" * (width + 36))
    for name, value, unit, target in rows:
        shown = "n/a" if value is None else f"{value:,.0f}"
        print(f"{name.ljust(width)}  {shown:>10}  {unit:<8}  {target}")
    for label, result in (("without", plain), ("with", sensed)):
        if result is None:
            continue
        s = result["sim"]
        if s["stopped"] or s["refused_commands"] or s["timeouts"]:
            print(f"WARNING run {label} sensor: stopped={s['stopped']} ({s['stop_reason']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
