"""Command authority of the simulated machine (pure, no rclpy): which drive commands
the plant applies.

Nothing but the controller the plant was connected to may move it (ros2_control's
hardware/controller boundary, made explicit):

* **Source.** ``command_source`` names the controller node (``/pkm/controller``); empty:
  the one publisher on ``drives/command`` when the first command arrives. Any other
  publisher on the topic, at any time, is an intruder (pkm_common.sources, which the
  controller uses for its own inputs the other way round): the plant holds safe and
  the diagnostics name it. The node counts the publishers matched to its
  subscription and asks the graph who publishes at the first command and on every
  watchdog tick.
  (Each publisher numbers its messages, but rclpy 7.1.6's EventsExecutor raises a
  SystemError for a raw subscription that asks for the message info, so the numbers
  are not used.)
* **Stamps.** A command answers a published state: one stamped after the plant's
  current step is refused; in real time one older than ``max_age_ns`` is refused too
  (in lockstep older stamps are the discovery repeats, counted as stale).

Every refusal is counted and kept as a :class:`Refusal` for the node to record.
"""

from __future__ import annotations

from dataclasses import dataclass

from pkm_common.causes import TripCause
from pkm_common.sources import Intrusion, SourceGate
from pkm_kinematics.errors import FieldError

__all__ = ["CommandGate", "Refusal", "STALE", "APPLY"]

APPLY = "apply"
STALE = "stale"


@dataclass(frozen=True)
class Refusal:
    """A command the plant did not apply: why, the cause class, the stamp, the sender
    when it is known (a node name), and whether it must stop the machine."""

    reason: str
    cause: TripCause
    stamp_ns: int = -1
    sender: str = ""
    stop: bool = True


class CommandGate:
    """Decides, per command, apply / stale / refuse (see the module docstring)."""

    def __init__(self, command_source: str, lockstep: bool, max_age_ns: int):
        if max_age_ns <= 0:
            raise FieldError("command_max_age_s", f"must be > 0, got {max_age_ns * 1e-9:g} s")
        self.sources = SourceGate("drives/command", command_source, "command_source")
        self.lockstep = lockstep
        self.max_age_ns = max_age_ns

    def check_stamp(self, stamp_ns: int, now_ns: int) -> str | Refusal:
        """APPLY, STALE (lockstep: an answer to an older state) or a Refusal."""
        if stamp_ns > now_ns:
            return Refusal(f"stamp {stamp_ns * 1e-9:.6f} s is ahead of the plant's step {now_ns * 1e-9:.6f} s",
                           TripCause.INPUT_REFUSED, stamp_ns)
        if stamp_ns == now_ns:
            return APPLY
        if self.lockstep:
            return STALE
        if now_ns - stamp_ns > self.max_age_ns:
            return Refusal(f"stamp {stamp_ns * 1e-9:.6f} s is {(now_ns - stamp_ns) * 1e-6:.3f} ms old "
                           f"(command_max_age_s {self.max_age_ns * 1e-9:g})", TripCause.INPUT_REFUSED,
                           stamp_ns, stop=False)
        return APPLY

    def check_publishers(self, publishers: list[str], matched: int = 1) -> Refusal | None:
        """The fully qualified names of the nodes publishing drives/command, one per
        publisher: any other than the controller, or a second publisher under its
        name (an orphan of an earlier run), or more ``matched`` publishers than named,
        is an intruder (pkm_common.sources). Before the controller is known (no
        ``command_source``, no command yet) nothing is decided."""
        return _refused(self.sources.check(publishers, matched))

    def connect(self, publishers: list[str], matched: int = 1) -> Refusal | None:
        """At the first command: the controller is the expected one, or else the one
        publisher there is; two publishers (``matched`` to the subscription, named or
        not yet) without a ``command_source`` are refused."""
        return _refused(self.sources.connect(publishers, matched))


def _refused(intrusion: Intrusion | None) -> Refusal | None:
    return None if intrusion is None else Refusal(intrusion.reason, TripCause.INTRUDER, sender=intrusion.sender)
