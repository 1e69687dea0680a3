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

from pkm_common.params import ParameterValues
from pkm_kinematics.errors import FieldError
from pkm_trajectory.planner import Samples
from pkm_trajectory.planning import declare_planner

__all__ = ["plan_program", "spindle_load_entries"]

SPINDLE_KEYS = ("wrench", "ramp_s", "reference_rpm")


def plan_program(program_text: str, machine: str, p: dict) -> Samples:
    """The program planned and validated as trajectory_node plans it, from the machine's
    home: its declarations over ``p`` (its parameters: the node's defaults and the
    scenario's trajectory section, typed as the node gets them) and ``machine`` (the
    controller's model). The plan is kept (planning.PlannerSettings.plan_program): a
    run in one process, or a study's, plans it once."""
    settings = declare_planner(ParameterValues({**p, "machine": machine}))
    return settings.plan_program(program_text, settings.config.model.home.tolist())


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
