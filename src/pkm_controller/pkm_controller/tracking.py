"""The reference the controller follows (pure core, no rclpy): a trajectory
(reference.Reference) on the feed clock (feed.FeedClock: the trajectory's time under
the operator's override), the hold where the machine is at the first cycle, and the
trajectories an operator or the planner gives, each checked to start where the
reference is.
"""

from __future__ import annotations

from dataclasses import dataclass

from pkm_kinematics.errors import FieldError
from pkm_kinematics.task_space import SPATIAL

from .feed import FeedClock, scaled_reference
from .laws import error_norms, task_pose_error
from .reference import Reference, approach_duration, with_approach

__all__ = ["Approach", "ReferenceTracker"]


@dataclass(frozen=True)
class Approach:
    """A trajectory that starts beyond the start tolerances but within ``max_m`` and
    ``max_rad`` of the reference is taken after a minimum-jerk move to its start
    (reference.with_approach) within peak speeds and accelerations, sampled every
    ``dt_s``: as a CNC's program starts from wherever the machine is. A machine homed on
    its drives with a model error believes itself millimetres from the configured home
    where the program was planned from (ControllerConfig.start_approach_m). With a
    ``fixed_s`` duration every trajectory starts with an approach that long (a hold
    where it starts at the reference): the program's timing is the same whatever the
    start (a study's load schedule, in the run's time, meets the same motion)."""

    max_m: float
    max_rad: float
    speed_m_s: float
    speed_rad_s: float
    acceleration_m_s2: float
    acceleration_rad_s2: float
    fixed_s: float
    dt_s: float

    @classmethod
    def of(cls, config) -> "Approach | None":
        """The approach of a ControllerConfig; None when it has none."""
        c = config
        if c.start_approach_m == 0.0 and c.start_approach_rad == 0.0:
            return None
        return cls(c.start_approach_m, c.start_approach_rad, c.approach_speed_m_s, c.approach_speed_rad_s,
                   c.approach_acceleration_m_s2, c.approach_acceleration_rad_s2, c.approach_duration_s, c.dt_s)

    def duration_s(self, distance_m: float, angle_rad: float) -> float:
        if self.fixed_s > 0.0:
            return self.fixed_s
        return approach_duration(distance_m, angle_rad, self.speed_m_s, self.speed_rad_s, self.acceleration_m_s2,
                                 self.acceleration_rad_s2)


class ReferenceTracker:
    """``space``: the machine's task space; a trajectory must start within
    ``start_tolerance_m`` and ``start_tolerance_rad`` of the current reference;
    ``twists(x, v, a)``: the rates as the laws take them (commands.SixAxis.twists), None
    when they are the coordinates' own."""

    def __init__(self, space, start_tolerance_m: float, start_tolerance_rad: float, twists=None,
                 approach: Approach | None = None):
        if approach is not None and space is SPATIAL:
            name = "start_approach_m" if approach.max_m > 0.0 else "start_approach_rad"
            raise FieldError(name, "approach moves are for the 3-DOF machines (planar, translational): 0 on a "
                                   "6-DOF machine")
        self.space, self.twists, self.approach = space, twists, approach
        self.start_tolerance_m, self.start_tolerance_rad = start_tolerance_m, start_tolerance_rad
        self.last_approach: dict | None = None   # the last approach move: distance_m, angle_rad, duration_s
        self.reference: Reference | None = None  # None before the first cycle
        self.feed = FeedClock()
        self.pending: Reference | None = None    # given before the first cycle: started by hold()

    def mode(self, now_s: float | None) -> str:
        """"tracking" while a trajectory runs at ``now_s`` (the last cycle's time), else "holding"."""
        if self.reference is None or self.reference.duration_s == 0.0:
            return "holding"
        return "tracking" if now_s is not None and self.feed.peek(now_s) < self.reference.duration_s else "holding"

    def set_trajectory(self, reference: Reference, now_s: float | None) -> dict | None:
        """Start ``reference`` at ``now_s``; before the first cycle it waits for hold().
        Refused (ValueError, nothing changes) when it does not start at the current
        reference (within the approach's bounds: taken after a move to its start,
        returned as {distance_m, angle_rad, duration_s}). The caller refuses it while
        stopped or tracking."""
        if self.reference is None:               # no state yet: checked at the first cycle
            self.pending = reference
            return None
        current, _, _ = self.reference.sample(self.feed.peek(now_s))
        reference, approach = self.starting(reference, current)
        self.reference = reference
        self.feed.restart(now_s)
        if approach is not None:
            self.last_approach = approach
        return approach

    def starting(self, reference: Reference, current) -> tuple[Reference, dict | None]:
        """(the reference to run, None) when ``reference`` starts within the start
        tolerances of ``current``; (it preceded by an approach move, the approach) within
        the approach's bounds; else ValueError naming the distance and the bounds."""
        dof = self.space.dof
        if len(reference.start) != dof:
            raise ValueError(f"trajectory refused: {len(reference.start)} task coordinates, this machine has "
                             f"{dof} ({self.space.describe()})")
        offset = task_pose_error(reference.start, current, self.space)
        dist, angle = error_norms(offset, self.space)
        a = self.approach
        if dist <= self.start_tolerance_m and angle <= self.start_tolerance_rad and (a is None or not a.fixed_s):
            return reference, None
        if a is not None and dist <= max(a.max_m, self.start_tolerance_m) and \
                angle <= max(a.max_rad, self.start_tolerance_rad):
            duration = a.duration_s(dist, angle)
            approached = with_approach(reference, offset, duration, a.dt_s)
            return approached, {"distance_m": dist, "angle_rad": angle,
                                "duration_s": round(approached.duration_s - reference.duration_s, 9)}
        bounds = "" if a is None else f", start_approach_m {a.max_m:g}, start_approach_rad {a.max_rad:g}"
        raise ValueError(f"trajectory refused: it starts at {[round(v, 6) for v in reference.start]}, "
                         f"{dist * 1e3:.3f} mm / {angle:.4f} rad from the "
                         f"current reference {[round(v, 6) for v in current]} (start_tolerance_m "
                         f"{self.start_tolerance_m:g}, start_tolerance_rad {self.start_tolerance_rad:g}{bounds})")

    def hold(self, pose, now_s: float) -> str | None:
        """The first cycle: hold at ``pose`` from ``now_s``, then start a trajectory
        given before it. Returns why that one was refused (the machine holds), None
        when none was or it started."""
        self.reference = Reference.hold(pose)
        self.feed.restart(now_s)
        if self.pending is None:
            return None
        pending, self.pending = self.pending, None
        try:
            self.set_trajectory(pending, now_s)
        except ValueError as exc:
            return str(exc)
        return None

    def sample(self, t_s: float):
        """(x_d, v_d, a_d) of the cycle at ``t_s``: the feed clock advanced, the
        reference sampled at its time, its rates scaled (and made twists)."""
        tau, s, sdot = self.feed.advance(t_s)
        x_d, v_d, a_d = scaled_reference(self.reference.sample(tau), s, sdot)
        if self.twists is None:
            return x_d, v_d, a_d
        return (x_d, *self.twists(x_d, v_d, a_d))
