"""The controller core against the plant core in lockstep, without ROS (pure core).

The same exchange the node graph makes (state k -> [sensor k] -> command k -> step),
as a plain loop, for tests, parameter studies and benchmarks (several times faster
than the node graph). That the graph reproduces these numbers exactly is not yet
tested (issue 6 asks for the in-process / multi-process comparison).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pkm_kinematics.config import MachineConfig

from .config import ControllerConfig

from .controller import ControllerCore
from .laws import tool_pose_floats
from .strategies import Feedback


@dataclass
class LoopLog:
    """Per-cycle arrays of a closed-loop run (N cycles)."""

    time_s: list = field(default_factory=list)
    reference: list = field(default_factory=list)      # task x_d
    tool: list = field(default_factory=list)           # true tool pose (deflection included)
    rigid: list = field(default_factory=list)          # true platform pose without deflection
    forces: list = field(default_factory=list)         # commands
    applied: list = field(default_factory=list)        # what the drives applied
    internal_force_norm_n: list = field(default_factory=list)   # true (plant) internal force

    def arrays(self) -> dict:
        return {k: np.asarray(v) for k, v in self.__dict__.items()}

    def tool_error(self, planar: bool) -> np.ndarray:
        """|x_d - tool| translation per cycle (m)."""
        d = np.asarray(self.reference) - np.asarray(self.tool)
        return np.hypot(d[:, 0], d[:, 1]) if planar else np.linalg.norm(d, axis=1)


def run(machine: MachineConfig, controller: ControllerConfig | ControllerCore, plant, steps: int,
        reference=None, sensor=None, load=None, on_cycle=None) -> tuple[ControllerCore, LoopLog]:
    """Run ``steps`` lockstep cycles.

    ``plant``: a pkm_sim_hw Plant. ``sensor``: a GoughSensorModel measuring the true
    tool (needed by the metrology strategies). ``reference``: a Reference started at
    the first cycle. ``load``: a function t -> task wrench on the tool. ``on_cycle``:
    called with (k, core, plant_output) after every cycle (fault injection in tests).
    """
    core = controller if isinstance(controller, ControllerCore) else ControllerCore(machine, controller)
    planar = core.planar
    if reference is not None:
        core.set_trajectory(reference)
    log = LoopLog()
    out = plant.output()
    for k in range(steps):
        if load is not None:
            plant.set_load(load(out.time_s))
        struts = pose = None
        if sensor is not None:
            p, r = tool_pose_floats(out.tool_pose, planar) if out.tool_rotation is None else \
                (tuple(out.tool_pose[:3]), out.tool_rotation)
            rot = np.array(r).reshape(3, 3)
            struts = sensor.measure(p, rot)
            if core.strategy.feedback == Feedback.GOUGH_POSE:
                position, rotation, result = sensor.estimate(struts)
                pose = (position.tolist(), rotation) if result.converged else None
            struts = struts.tolist()
        forces = core.update(out.stamp_ns, out.encoder_positions, out.encoder_velocities, out.applied_forces,
                             struts=struts, metrology_pose=pose)
        log.time_s.append(out.time_s)
        log.reference.append(list(core.record.reference))
        log.tool.append(list(out.tool_pose))
        log.rigid.append(list(out.rigid_pose))
        log.forces.append(list(forces))
        log.applied.append(list(out.applied_forces))
        log.internal_force_norm_n.append(out.internal_force_norm)
        out = plant.step(forces)
        if on_cycle is not None:
            on_cycle(k, core, out)
    return core, log
