"""trajectory_node's parameters as one value, and what it does with a program or a goal
without rclpy: plan, validate (planner.plan_validated). Declared on the node, or on a
pkm_common.params.ParameterValues by the direct engine (pkm_bringup.direct), with the
same checks.
"""

from __future__ import annotations

import collections
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from pkm_common.params import declare_float, declare_float_list, declare_int, declare_str
from pkm_kinematics import load_machine
from pkm_kinematics.config import MachineConfig, config_dir
from pkm_kinematics.dynamics import dynamic_model
from pkm_trajectory.planner import RATE_HZ_RANGE, Limits, PlanBudget, Samples, plan_validated
from pkm_trajectory.program import gcode_segments
from pkm_trajectory.tool_table import load_tool_table

__all__ = ["PLAN_CACHE_SIZE", "PlannerSettings", "declare_planner"]

# programs planned per process, kept: the runs of a study, and the two engines of a
# comparison, plan the same program from the same pose with the same settings (tens of
# seconds for a hexapod's): the last few plans are kept (a plan's samples are read, never changed)
PLAN_CACHE_SIZE = 4
_PLANS: collections.OrderedDict = collections.OrderedDict()
_PLANS_LOCK = threading.Lock()


@dataclass(frozen=True)
class PlannerSettings:
    config: MachineConfig
    limits: Limits
    rate_hz: float
    joint_velocity: float
    joint_acceleration: float
    max_condition: float
    feed_override: float
    scale: float
    repeat: int
    blend_tolerance: float
    budget: PlanBudget
    drive_force: float | None          # N; None: no force limit
    dynamics: object                   # the machine's dynamic model where a force limit needs it
    drive_jerk: float | None
    tools: dict | None
    program_file: str
    key: tuple = field(default=(), compare=False)     # the declared values (plan_program's cache)

    def gcode_options(self, start_pose) -> dict:
        space = self.config.model.task_space
        return {"space": space, "start_pose": start_pose, "feed_override": self.feed_override, "scale": self.scale,
                "repeat": self.repeat, "tools": self.tools, "max_moves": self.budget.max_segments,
                "deadline": time.monotonic() + self.budget.max_planning_s}

    def program_segments(self, text: str, start_pose) -> list:
        """A G-code program's segments from ``start_pose`` (program.gcode_segments)."""
        return gcode_segments(text, **self.gcode_options(start_pose))

    def plan_program(self, text: str, start_pose) -> Samples:
        """A G-code program planned from ``start_pose`` (program_segments, plan); the
        same program from the same pose with the same settings is planned once per
        process (the last PLAN_CACHE_SIZE kept)."""
        key = (self.key, text, tuple(float(v) for v in start_pose))
        with _PLANS_LOCK:
            found = _PLANS.get(key)
            if found is not None:
                _PLANS.move_to_end(key)
                return found
        found = self.plan(self.program_segments(text, start_pose))
        with _PLANS_LOCK:
            _PLANS[key] = found
            while len(_PLANS) > PLAN_CACHE_SIZE:
                _PLANS.popitem(last=False)
        return found

    def plan(self, segments) -> Samples:
        """Planned, sampled and checked against the machine; raises TrajectoryRejected
        (or ValueError) naming the sample and the limit."""
        return plan_validated(segments, self.config.model, self.limits, self.rate_hz, self.blend_tolerance,
                              self.joint_velocity, self.joint_acceleration, self.max_condition, self.budget,
                              self.drive_force, self.dynamics, self.drive_jerk)


def declare_planner(node) -> PlannerSettings:
    """trajectory_node's parameters (a bad one raises ParameterError naming it)."""
    machine = declare_str(node, "machine", "archi")
    config = load_machine(machine)
    space = config.model.task_space
    # per task axis: m/s (m/s^2, m/s^3) for a translation, rad/s ... for an angle
    defaults = {name: [per_axis[0]] * space.translation_axes + [per_axis[1]] * (space.dof - space.translation_axes)
                for name, per_axis in (("max_velocity", (0.5, 2.0)), ("max_acceleration", (5.0, 20.0)),
                                       ("max_jerk", (200.0, 800.0)))}
    limits = Limits(*(tuple(declare_float_list(node, name, default, length=space.dof, lo=0.0))
                      for name, default in defaults.items()))
    rate_hz = declare_float(node, "rate_hz", 1000.0, *RATE_HZ_RANGE, unit="Hz")
    joint_velocity = declare_float(node, "max_joint_velocity", 2.0, 0.0, 100.0, lo_open=True, unit="m/s")
    joint_acceleration = declare_float(node, "max_joint_acceleration", 50.0, 0.0, 1e4, lo_open=True, unit="m/s^2")
    max_condition = declare_float(node, "max_condition", 50.0, 1.0, 1e12)
    feed_override = declare_float(node, "feed_override", 1.0, 0.0, 2.0, lo_open=True)
    scale = declare_float(node, "scale", 1.0, 0.0, 100.0, lo_open=True)
    repeat = declare_int(node, "repeat", 1, 1, 10000)
    blend_tolerance = declare_float(node, "blend_tolerance_m", 0.0, 0.0, 0.01,
                                    "corner blending of line moves (0: exact stop)", unit="m")
    # a plan's size is known before it is sampled, and refused beyond these (planner.PlanBudget)
    budget = PlanBudget(
        declare_int(node, "max_points", 200_000, 2, 10_000_000,
                    "longer trajectories are refused (message size and memory)"),
        declare_int(node, "max_segments", 10_000, 1, 1_000_000, "programs of more segments are refused"),
        declare_float(node, "max_planning_s", 10.0, 0.0, 3600.0, "corner blending that takes longer is refused",
                      lo_open=True, unit="s"))
    # drive forces kept by slowing down (the machine's dynamic model; 0: no force limit)
    force = declare_float(node, "max_drive_force_n", 0.0, 0.0, 1e7, "drive force limit kept by the plan "
                          "(0: none)", unit="N")
    drive_force = force if force > 0.0 else None
    jerk = declare_float(node, "max_joint_jerk", 0.0, 0.0, 1e7, "drive jerk limit of the motion slowed down for "
                         "the drives (0: the task axes' jerk only)", unit="m/s^3")
    table = declare_str(node, "tool_table", "", "LinuxCNC tool.tbl (mm) that G43 H reads", allow_empty=True)
    program_file = declare_str(node, "program_file", "", "G-code file planned at start", allow_empty=True)
    key = (machine, _version(machine), limits, rate_hz, joint_velocity, joint_acceleration, max_condition,
           feed_override, scale, repeat, blend_tolerance, budget, force, jerk, table, _version(table))
    return PlannerSettings(config, limits, rate_hz, joint_velocity, joint_acceleration, max_condition, feed_override,
                           scale, repeat, blend_tolerance, budget, drive_force,
                           dynamic_model(config) if drive_force is not None else None, jerk if jerk > 0.0 else None,
                           load_tool_table(table) if table else None, program_file, key)


def _version(name_or_path: str) -> tuple:
    """A file's identity and version (modification time ns, size, inode), for a machine
    given by name its file in config/machines: a file written again (a machine
    calibrated again, a tool table) is another plan. () for nothing."""
    if not name_or_path:
        return ()
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml", ".tbl") and os.sep not in name_or_path:
        path = config_dir() / "machines" / f"{name_or_path}.yaml"
    try:
        found = path.stat()
    except OSError:
        return (str(path),)
    return str(path.resolve()), found.st_mtime_ns, found.st_size, found.st_ino
