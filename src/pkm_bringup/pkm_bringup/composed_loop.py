"""The loop's nodes composed in one process (scenario key ``loop_process: composed``, the
default with the realtime profile): ``python -m pkm_bringup.composed_loop <params dir>
<node> ... --ros-args -r __ns:=<ns>`` builds the simulated machine (sim_hw), its
instruments (gough_sensor, laser_tracker) and the controller, each from its own
``<params dir>/<node>.yaml``, on one context, and spins them with one executor
(pkm_common.runner.run_nodes). They stay separate nodes exchanging their messages over
their topics (each with its name, the publishers it accepts, its summary); what goes
is the process boundary on the loop's critical path: three processes on two cores
handed each step's messages on through the kernel and each other's scheduling, the
loop missed ~5x the deadlines of a bare three-process chain at 1 kHz; one process
~2x (benchmarks/realtime.py, docs/decisions.md). The process ends with the run,
``END_GRACE_S`` after sim_hw's last step (the last state answered), its nodes torn
down while their context is up (their taps' last batches reach the recorder: sim_hw
does not shut the context down here, as in one executor). Its log is ``logs/loop.log``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import yaml
from rclpy.parameter import Parameter

from pkm_common.runner import main_exit, run_nodes

__all__ = ["COMPOSED", "main"]

COMPOSED = ("sim_hw", "gough_sensor", "laser_tracker", "controller")     # in this order
END_GRACE_S = 0.15         # after the plant's last step (graph.LOOP_END_GRACE_S)


def _classes() -> dict:
    from pkm_controller.controller_node import ControllerNode
    from pkm_gough_sensor.gough_sensor_node import GoughSensorNode
    from pkm_gough_sensor.laser_tracker_node import LaserTrackerNode
    from pkm_sim_hw.sim_hw_node import SimHwNode
    return {"sim_hw": SimHwNode, "gough_sensor": GoughSensorNode, "laser_tracker": LaserTrackerNode,
            "controller": ControllerNode}


def _factory(name: str, cls, params_file: Path, **changed):
    """``cls`` built with the parameters of its params file (pkm-run's, ``/**``); a
    refused configuration names the node (they share one log)."""
    values = {**yaml.safe_load(params_file.read_text(encoding="utf-8"))["/**"]["ros__parameters"], **changed}
    overrides = [Parameter(key, value=value) for key, value in values.items()]

    def build(context):
        try:
            return cls(context=context, parameter_overrides=overrides)
        except ValueError as exc:
            raise ValueError(f"node {name} refused its configuration: {exc}") from exc
    return build


def main(argv=None) -> int | None:
    """Exits with the nodes' code (runner.main_exit); returns 2 on a usage error."""
    argv = list(sys.argv[1:] if argv is None else argv)
    split = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    (params_dir, *names), ros_args = argv[:split] or [""], argv[split:]
    unknown = [name for name in names if name not in COMPOSED]
    if not params_dir or "sim_hw" not in names or unknown:
        print(f"usage: python -m pkm_bringup.composed_loop <params dir> <node> ... --ros-args ...; nodes: one or "
              f"more of {', '.join(COMPOSED)} with sim_hw, got {names}", file=sys.stderr)
        return 2
    classes = _classes()
    factories = [_factory(name, classes[name], Path(params_dir) / f"{name}.yaml",
                          **({"shutdown_on_finish": False} if name == "sim_hw" else {}))
                 for name in COMPOSED if name in names]
    finished = []

    def done(nodes) -> bool:
        if not finished and nodes[0].finished:
            finished.append(time.monotonic())
        return bool(finished) and time.monotonic() > finished[0] + END_GRACE_S
    main_exit(run_nodes(factories, args=["composed_loop", *ros_args], executor="events", name="loop", done=done,
                        spin_period_s=0.02))


if __name__ == "__main__":
    sys.exit(main())
