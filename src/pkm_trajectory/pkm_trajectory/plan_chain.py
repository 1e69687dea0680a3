"""Where trajectory_node's next plan starts (pure, no rclpy): the end of the last
trajectory the controller accepted, not of the last one published. The controller
judges each trajectory on ``controller/events`` (a JSON record of kind "trajectory",
ok or refused), in the order it received them. Before, a refused goal still moved the
planner's pose to its end: the next plan started where the machine was not, and inside
the start tolerance the reference jumped to it in one step."""

from __future__ import annotations

import collections
import json

__all__ = ["PlanChain", "trajectory_verdict"]

PENDING_MAX = 64          # trajectories published and not judged yet (the controller judges each in a cycle)


def trajectory_verdict(text: str) -> bool | None:
    """The controller's verdict on a trajectory from one controller/events record:
    True accepted, False refused, None for any other record (or one not readable)."""
    try:
        event = json.loads(text)
    except ValueError:
        return None
    if not isinstance(event, dict) or event.get("kind") != "trajectory":
        return None
    return bool(event.get("ok"))


class PlanChain:
    """The start of the next plan: the end of the newest trajectory still awaiting its
    verdict (plans chain, as a program's moves do), else of the last accepted one. A
    refusal drops the trajectories chained on it: they started where the machine will
    not be (the controller refuses them too, each with its own verdict, then ignored)."""

    def __init__(self, pose):
        self.accepted = [float(v) for v in pose]
        self.pending: collections.deque = collections.deque(maxlen=PENDING_MAX)

    def start(self) -> list:
        return list(self.pending[-1] if self.pending else self.accepted)

    def published(self, end) -> None:
        self.pending.append([float(v) for v in end])

    def verdict(self, ok: bool) -> bool:
        """The controller judged the oldest pending trajectory; False when none was
        pending (a verdict on someone else's, or replayed from before this planner)."""
        if not self.pending:
            return False
        end = self.pending.popleft()
        if ok:
            self.accepted = end
        else:
            self.pending.clear()
        return True
