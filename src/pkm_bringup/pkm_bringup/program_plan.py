"""A scenario's program planned when the scenario is loaded (pure, no rclpy): exactly as
trajectory_node will plan it (a program it would refuse fails here, before anything
starts), for the run's duration and for the spindle load its events switch on and off.

``spindle_load`` (a scenario key, lockstep only): the cutting load the simulated plant
carries while the program's spindle turns (M3/M4 with S > 0), ``wrench`` in the
machine's load components, scaled by S / ``reference_rpm`` when given, reached over
``ramp_s`` (a tool entering the material) and gone at M5. The trajectory starts with
the run (the controller waits for it), so an event's time along the trajectory is its
simulated time.
"""

from __future__ import annotations

import math

from pkm_kinematics.dynamics import dynamic_model
from pkm_kinematics.errors import FieldError
from pkm_trajectory.planner import Limits, PlanBudget, Samples, plan_validated
from pkm_trajectory.program import gcode_segments
from pkm_trajectory.tool_table import load_tool_table

__all__ = ["plan_program", "spindle_load_entries"]

SPINDLE_KEYS = ("wrench", "ramp_s", "reference_rpm")


def plan_program(program_text: str, model, machine_config, p: dict) -> Samples:
    """The program planned and validated with trajectory_node's parameters ``p`` (its
    defaults and the scenario's trajectory section) from the machine's home."""
    tools = load_tool_table(p["tool_table"]) if p.get("tool_table") else None
    segments = gcode_segments(program_text, model.task_space, start_pose=[float(v) for v in model.home],
                              tools=tools, feed_override=float(p.get("feed_override", 1.0)),
                              scale=float(p.get("scale", 1.0)), repeat=int(p.get("repeat", 1)))
    force = float(p.get("max_drive_force_n", 0.0)) or None
    limits = Limits(tuple(p["max_velocity"]), tuple(p["max_acceleration"]), tuple(p["max_jerk"]))
    return plan_validated(segments, model, limits, float(p.get("rate_hz", 1000.0)),
                          float(p.get("blend_tolerance_m", 0.0)), float(p.get("max_joint_velocity", 2.0)),
                          float(p.get("max_joint_acceleration", 50.0)), float(p.get("max_condition", 50.0)),
                          PlanBudget(int(p.get("max_points", 200_000)), int(p.get("max_segments", 10_000)),
                                     float(p.get("max_planning_s", 10.0))),
                          force, dynamic_model(machine_config) if force else None,
                          float(p.get("max_joint_jerk", 0.0)) or None)


def spindle_load_entries(events: list, spec, size: int) -> list[dict]:
    """The load schedule ({t_s, wrench, ramp_s} entries, scenario._load_profile's) of a
    plan's spindle events (planner.Samples.events) under ``spec`` (module doc); a ramp
    is cut short where the next change comes first."""
    if not isinstance(spec, dict) or set(spec) - set(SPINDLE_KEYS) or "wrench" not in spec:
        raise FieldError("spindle_load", f"must be {{wrench: [{size} numbers], ramp_s: s (optional), "
                                         f"reference_rpm: rpm (optional)}}, got {spec!r}")
    wrench = spec["wrench"]
    if not isinstance(wrench, list) or len(wrench) != size or \
            not all(isinstance(w, (int, float)) and math.isfinite(w) for w in wrench):
        raise FieldError("spindle_load.wrench", f"expected {size} finite numbers (the machine's load components), "
                                                f"got {wrench!r}")
    ramp = spec.get("ramp_s", 0.0)
    reference = spec.get("reference_rpm")
    if not isinstance(ramp, (int, float)) or not 0.0 <= ramp <= 10.0:
        raise FieldError("spindle_load.ramp_s", f"must be in [0, 10] s, got {ramp!r}")
    if reference is not None and not (isinstance(reference, (int, float)) and reference > 0.0):
        raise FieldError("spindle_load.reference_rpm", f"must be > 0 rpm, got {reference!r}")
    changes = {}                                       # the last spindle state at each time
    for t, _, (name, data) in events:
        if name == "spindle":
            data = dict(data)
            on = data["direction"] != "stop" and data["rpm"] > 0.0
            scale = (data["rpm"] / reference if reference else 1.0) if on else 0.0
            changes[round(t, 9)] = [float(w) * scale for w in wrench]
    times = sorted(changes)
    if not times:
        raise FieldError("spindle_load", "the program never starts the spindle (M3/M4 with S > 0)")
    return [{"t_s": t, "wrench": changes[t], "ramp_s": min(float(ramp), (times[k + 1] - t) if k + 1 < len(times)
                                                            else float(ramp))}
            for k, t in enumerate(times)]
