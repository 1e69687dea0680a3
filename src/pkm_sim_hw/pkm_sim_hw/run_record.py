"""What sim_hw keeps of its run (pure, no rclpy): the counters, the intruder named,
the steps published, and from them the diagnostics' values and the summary written
at exit. The loop (sim_loop) keeps it; the node only publishes what it makes."""

from __future__ import annotations

from pkm_common.causes import TripCause
from pkm_common.poses import machine_pose_components, pose_components

from .authority import Refusal

# every counter of the run, in the diagnostics and the summary
COUNTERS = ("refused_commands", "stale_commands", "deadline_misses", "timeouts", "refused_loads",
            "refusals_not_published", "state_repeats")
# the streams published once per step (the discovery repeats not counted)
STEP_TOPICS = ("drives/state", "platform/true_pose", "/clock")
UNNAMED = "unknown"          # an intruder counted (a second publisher matched) before the graph names it


class RunRecord:
    """Counters and events of one sim_hw run (``counts`` is shared with the refusal
    report, which counts what it could not publish)."""

    def __init__(self, machine_name: str, lockstep: bool, homing: str = ""):
        self.machine_name, self.lockstep, self.homing = machine_name, lockstep, homing
        self.counts = dict.fromkeys(COUNTERS, 0)
        # the first intruder named (a node); UNNAMED while the graph has only counted a
        # second publisher (its name comes with discovery, later); "" while none
        self.intruder = ""
        self.steps_published = 0           # distinct steps on /clock, drives/state, platform/true_pose
        self.last_published_ns = -1
        self.first_command_wall = None     # monotonic seconds of the first command applied
        self.finished = False

    @property
    def intruder_named(self) -> bool:
        """An intruder was refused and named (not only counted)."""
        return self.intruder not in ("", UNNAMED)

    def published(self, ns: int) -> None:
        """The state of the step at ``ns`` went out (a repeat of it is not a step)."""
        if ns != self.last_published_ns:
            self.last_published_ns = ns
            self.steps_published += 1

    def refused(self, refusal: Refusal, topic: str) -> str:
        """Count a refusal (a load's or a command's), keep the first intruder's name
        (an unnamed one is named by the first refusal that names it); returns the text
        that says it."""
        load = topic == "load"
        self.counts["refused_loads" if load else "refused_commands"] += 1
        if refusal.cause == TripCause.INTRUDER and not self.intruder_named:
            self.intruder = refusal.sender or UNNAMED
        return f"refused {'load' if load else 'command'}: {refusal.reason}"

    def diagnostics(self, plant, out) -> tuple[int, str, dict]:
        """(level, message, values) of sim_hw's diagnostic status, the plant's output
        ``out`` (plant.Plant.output()) included."""
        level = 2 if plant.stopped else 0
        message = f"stopped: {plant.stop_reason}" if plant.stopped else "running"
        values = {"step": out.step, "time_s": out.time_s, "finished": self.finished,
                  "cause": str(plant.stop_cause), "intruder": self.intruder or "none",
                  "mode": "lockstep" if self.lockstep else "realtime",
                  "internal_force_norm_n": out.internal_force_norm, "saturated_drives": sum(out.saturated),
                  "faults": ",".join(out.faults_active) or "none", **self.counts}
        if self.homing:
            values["homing"] = self.homing
        return level, message, values

    def summary(self, plant, now: float) -> dict:
        """The run's summary at monotonic time ``now`` (summary_path, pkm-run's run.json)."""
        wall = now - (self.first_command_wall or now)
        return {"machine": self.machine_name, "steps": plant.k, "sim_time_s": plant.t,
                "wall_s": wall, "steps_per_s": plant.k / wall if wall > 0 else None,
                "stopped": plant.stopped, "stop_reason": plant.stop_reason,
                "cause": str(plant.stop_cause), "intruder": self.intruder, **self.counts,
                "published": dict.fromkeys(STEP_TOPICS, self.steps_published),
                "complete": self.finished, **({"homing": self.homing} if self.homing else {})}


def true_pose_components(space, out) -> tuple:
    """(position, orientation) of the plant output's true tool pose for
    ``platform/true_pose``: the tool of the task-space pose (task_space.pose_fields),
    or the plant's own rotation where it has one (the imperfect Delta's parasitic
    rotation, a hexapod's)."""
    if out.tool_rotation is None:
        return machine_pose_components(space, out.tool_pose)
    r = out.tool_rotation
    return pose_components(out.tool_pose[:3], (r[0:3], r[3:6], r[6:9]))
