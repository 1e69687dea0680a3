"""What controller_node decides without rclpy: the core from its parameters (errors
named as ROS parameters), the core's inputs from a metrology reading, and the
summary written at exit."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from pkm_common.poses import machine_pose_components, pose_from_components
from pkm_common.timing import percentiles_us
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError, ParameterError

from .config import ControllerConfig
from .controller import ControllerCore

CONFIG_FIELDS = frozenset(f.name for f in fields(ControllerConfig))

# the controller node's own parameters, beside ControllerConfig's (the scenario checks both)
NODE_PARAMETERS = {"machine": "archi", "state_timeout_s": 0.5, "metrology_timeout_s": 0.5,
                   "status_decimation": 100, "summary_path": "", "wait_for_trajectory": False,
                   "wait_for_start": False, "end_time_s": 0.0,
                   # full node names of the inputs' sources (node_loop; empty: the one publisher)
                   "state_source": "", "metrology_source": "",
                   # who may command (comma-separated full node names; empty: anyone): node_loop
                   "trajectory_source": "", "operator_sources": "",
                   # the run's key (pkm_common.credential; empty: commands need no credential)
                   "credential_file": ""}


def core_from_parameters(machine_name: str, config: ControllerConfig) -> ControllerCore:
    """The controller core of the machine ``machine_name`` (config/machines, or a
    machine file). A bad value raises ParameterError "parameter '<name>': <what is
    allowed>", the name being the node's parameter: a ControllerConfig field the core
    names (its FieldError), else ``machine`` (the file, or what the core refuses about
    the machine itself: no dynamics section)."""
    try:
        machine = load_machine(machine_name)
    except ValueError as exc:
        raise ParameterError("machine", str(exc)) from None
    try:
        return ControllerCore(machine, config)
    except FieldError as exc:
        if exc.name in CONFIG_FIELDS:
            raise ParameterError(exc.name, exc.detail) from None
        raise ParameterError("machine", str(exc)) from None
    except ValueError as exc:
        raise ParameterError("machine", str(exc)) from None


def warm_up(core: ControllerCore, cycles: int = 3) -> None:
    """A few cycles of a scratch core of the same machine and configuration, standing
    at home: what the loop's first cycles load or allocate on first use is done
    before the first real state. Cold, the first full cycle of a 250 Hz realtime
    graph answered its state 14-17 ms late (65 ms beside a browser drawing the panel),
    and the drives, holding their setpoint meanwhile, drifted 11 mm; warmed, 0.5 ms.
    ``core`` itself is not touched."""
    scratch = ControllerCore(core.machine, core.config)
    model = core.model
    home = model.home
    q = [float(v) for v in model.inverse_kinematics(home)]
    zeros = [0.0] * core.n
    struts = pose = None
    if core.metrology is not None:
        sensor = GoughSensorModel(core.machine.metrology)
        position, orientation = machine_pose_components(core.space, [float(v) for v in home])
        p, r = pose_from_components(position, orientation)
        struts = sensor.measure(p, r).tolist()
        estimate = sensor.estimate(np.asarray(struts))
        pose = (estimate[0].tolist(), estimate[1])
    dt_ns = round(core.config.dt_s * 1e9)
    for k in range(cycles):
        if scratch.prepare(k * dt_ns, q, zeros, zeros):
            scratch.complete(struts=struts, metrology_pose=pose)
    scratch.status()


def metrology_inputs(wait_for: str, reading) -> tuple[list | None, tuple | None]:
    """(struts, metrology_pose) for ControllerCore.complete from the reading the
    strategy waits for: ``"struts"`` a JointState's positions (m), ``"pose"`` a
    PoseStamped's position and orientation (pkm_common.cdr data); (None, None) for
    the encoder strategies. ValueError naming metrology/pose for a NaN or a
    non-unit quaternion."""
    if wait_for == "struts":
        return list(reading.position), None
    if wait_for == "pose":
        try:
            position_m, rotation = pose_from_components(reading.position, reading.orientation)
        except ValueError as exc:
            raise ValueError(f"metrology/pose: {exc}") from None
        return None, (position_m.tolist(), rotation)
    return None, None


def run_summary(core: ControllerCore, compute_s, response_s, answers: int) -> dict:
    """The node's summary at exit: the status values, whether it stopped, the compute
    and response time percentiles (us), and the answers published per topic."""
    _, message, values = core.status()
    out = {"message": message, **values, "stopped": core.stopped, **percentiles_us("compute", compute_s),
           **percentiles_us("response", response_s),
           "published": dict.fromkeys(("drives/command", "controller/reference"), answers)}
    if core.tracker.last_approach is not None:       # the last trajectory that started with an approach move
        out["start_approach"] = core.tracker.last_approach
    return out
