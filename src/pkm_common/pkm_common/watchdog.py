"""A wall-clock silence watchdog that does not count its own process's stalls (pure).

A node's watchdog timer checks how long an input has been silent. When the check
itself comes late, the node's process did not run for that long: its executor was
busy with another node's callback (every node of a run in one executor) or the host
stalled it. The input may then be waiting in the node's queue, so that gap is not
the input's silence; the silence before and after it is. Repeated stalls therefore
delay a trip, never prevent it.

Both ends of the lockstep loop use it: the controller for the drive states
(``pkm_controller.lockstep``), sim_hw for the drive commands.
"""

from __future__ import annotations

from pkm_kinematics.errors import FieldError

__all__ = ["SilenceWatchdog"]


class SilenceWatchdog:
    """Silence of one input in wall-clock seconds (``time.monotonic``).

    ``own_stall_s``: a check more than this after the previous one means this process
    was stalled (a few periods of the timer that calls :meth:`silence_s`).
    Disarmed (no silence) until the first :meth:`feed`.
    """

    __slots__ = ("own_stall_s", "last_fed_s", "last_check_s")

    def __init__(self, own_stall_s: float):
        if not own_stall_s > 0.0:
            raise FieldError("own_stall_s", f"must be > 0 s, got {own_stall_s!r}")
        self.own_stall_s = own_stall_s
        self.last_fed_s: float | None = None
        self.last_check_s: float | None = None

    def feed(self, now_s: float) -> None:
        """The input arrived at ``now_s`` (arms the watchdog)."""
        self.last_fed_s = now_s

    def disarm(self) -> None:
        """No silence until the next :meth:`feed`."""
        self.last_fed_s = None

    def silence_s(self, now_s: float) -> float | None:
        """Seconds of silence at ``now_s`` without this process's own stalls, or None
        when disarmed. Call it periodically."""
        last_check, self.last_check_s = self.last_check_s, now_s
        if self.last_fed_s is None:
            return None
        if last_check is not None and now_s - last_check > self.own_stall_s:
            self.last_fed_s = min(now_s, self.last_fed_s + (now_s - last_check))
        return now_s - self.last_fed_s
