"""Where trajectory_node's next plan starts (pure, no rclpy): the end of the last
trajectory the controller accepted, not of the last one published. The controller
judges each trajectory on ``controller/events`` (a JSON record of kind "trajectory",
ok or refused, naming the trajectory by its header stamp). Before, a refused goal still moved the
planner's pose to its end: the next plan started where the machine was not, and inside
the start tolerance the reference jumped to it in one step."""

from __future__ import annotations

import collections
import json

__all__ = ["PlanChain", "trajectory_verdict"]

PENDING_MAX = 64          # trajectories published and not judged yet (the controller judges each in a cycle)


def trajectory_verdict(text: str) -> tuple[bool, int | None] | None:
    """The controller's verdict on a trajectory from one controller/events record:
    (accepted, the trajectory's header stamp or None), None for any other record (or
    one not readable)."""
    try:
        event = json.loads(text)
    except ValueError:
        return None
    if not isinstance(event, dict) or event.get("kind") != "trajectory":
        return None
    stamp = event.get("stamp_ns")
    return bool(event.get("ok")), stamp if isinstance(stamp, int) else None


class PlanChain:
    """The start of the next plan: the end of the newest trajectory still awaiting its
    verdict (plans chain, as a program's moves do), else of the last accepted one. A
    refusal drops the trajectories chained on it: they started where the machine will
    not be (the controller refuses them too, each with its own verdict, then ignored)."""

    def __init__(self, pose):
        self.accepted = [float(v) for v in pose]
        self.pending: collections.deque = collections.deque(maxlen=PENDING_MAX)

    def start(self) -> list:
        return list(self.pending[-1][1] if self.pending else self.accepted)

    def published(self, end, stamp_ns: int | None = None) -> None:
        """A trajectory published, ending at ``end``; ``stamp_ns`` its header stamp, which
        the controller's verdict names."""
        self.pending.append((stamp_ns, [float(v) for v in end]))

    def verdict(self, ok: bool, stamp_ns: int | None = None) -> bool:
        """The controller judged the trajectory stamped ``stamp_ns`` (None: the oldest
        pending). The ones published before it and never judged were replaced on the
        latched topic before the controller read them: dropped. False when it is none of
        ours (someone else's, or replayed from before this planner)."""
        stamps = [s for s, _ in self.pending]
        if stamp_ns is None:
            k = 0 if self.pending else -1
        else:
            k = stamps.index(stamp_ns) if stamp_ns in stamps else -1
        if k < 0:
            return False
        end = self.pending[k][1]
        for _ in range(k + 1):
            self.pending.popleft()
        if ok:
            self.accepted = end
        else:
            self.pending.clear()
        return True
