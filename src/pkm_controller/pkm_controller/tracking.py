"""The reference the controller follows (pure core, no rclpy): a trajectory
(reference.Reference) on the feed clock (feed.FeedClock: the trajectory's time under
the operator's override), the hold where the machine is at the first cycle, and the
trajectories an operator or the planner gives, each checked to start where the
reference is.
"""

from __future__ import annotations

from .feed import FeedClock, scaled_reference
from .laws import error_norms, task_pose_error
from .reference import Reference

__all__ = ["ReferenceTracker"]


class ReferenceTracker:
    """``space``: the machine's task space; a trajectory must start within
    ``start_tolerance_m`` and ``start_tolerance_rad`` of the current reference;
    ``twists(x, v, a)``: the rates as the laws take them (commands.SixAxis.twists), None
    when they are the coordinates' own."""

    def __init__(self, space, start_tolerance_m: float, start_tolerance_rad: float, twists=None):
        self.space, self.twists = space, twists
        self.start_tolerance_m, self.start_tolerance_rad = start_tolerance_m, start_tolerance_rad
        self.reference: Reference | None = None  # None before the first cycle
        self.feed = FeedClock()
        self.pending: Reference | None = None    # given before the first cycle: started by hold()

    def mode(self, now_s: float | None) -> str:
        """"tracking" while a trajectory runs at ``now_s`` (the last cycle's time), else "holding"."""
        if self.reference is None or self.reference.duration_s == 0.0:
            return "holding"
        return "tracking" if now_s is not None and self.feed.peek(now_s) < self.reference.duration_s else "holding"

    def set_trajectory(self, reference: Reference, now_s: float | None) -> None:
        """Start ``reference`` at ``now_s``; before the first cycle it waits for hold().
        Refused (ValueError, nothing changes) when it does not start at the current
        reference. The caller refuses it while stopped or tracking."""
        if self.reference is None:               # no state yet: checked at the first cycle
            self.pending = reference
            return
        current, _, _ = self.reference.sample(self.feed.peek(now_s))
        self.check_start(reference, current)
        self.reference = reference
        self.feed.restart(now_s)

    def check_start(self, reference: Reference, current) -> None:
        dof = self.space.dof
        if len(reference.start) != dof:
            raise ValueError(f"trajectory refused: {len(reference.start)} task coordinates, this machine has "
                             f"{dof} ({self.space.describe()})")
        dist, angle = error_norms(task_pose_error(reference.start, current, self.space), self.space)
        if dist > self.start_tolerance_m or angle > self.start_tolerance_rad:
            raise ValueError(f"trajectory refused: it starts at {[round(v, 6) for v in reference.start]}, "
                             f"{dist * 1e3:.3f} mm / {angle:.4f} rad from the "
                             f"current reference {[round(v, 6) for v in current]} (start_tolerance_m "
                             f"{self.start_tolerance_m:g}, start_tolerance_rad {self.start_tolerance_rad:g})")

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
