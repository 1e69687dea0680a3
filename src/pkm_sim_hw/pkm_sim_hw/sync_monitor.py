"""The drives' sync error counter in realtime mode (pure, no rclpy).

A drive on a cyclic bus applies, on every cycle, the last setpoint it received; when
the controller's command for a cycle misses it, the drive holds the previous one. An
EtherCAT drive counts such cycles with a leaky counter (ETG.1020, object 0x10F1:02
"Sync Error Counter Limit"): +3 for each cycle without a fresh setpoint, -1 for each
cycle with one, and a fault when the count exceeds its limit. The counter tolerates a
burst of up to ``limit // 3`` held setpoints and any sustained miss rate below 25 %
(3 r - (1 - r) < 0); anything worse means the controller cannot keep the cycle, and
the plant brakes naming that as the cause (``TripCause.DEADLINE_MISSED``), before the
stale setpoints show up as a following error or a drive that looks broken. When no
command at all came during the held cycles, the controller is silent, not late: the
cause is then ``TripCause.WATCHDOG`` (found within a few cycles, long before the
command timeout).
"""

from __future__ import annotations

from pkm_common.causes import TripCause
from pkm_kinematics.errors import FieldError

MISS_WEIGHT, ON_TIME_CREDIT = 3, 1       # ETG.1020 0x10F1:02


class SyncErrorCounter:
    """``update(missed, arrived)`` once per plant cycle (``arrived``: a command of any
    age came during the cycle); True when the count first exceeds ``limit`` (0: never:
    the check is off), and then ``tripped`` says why and ``cause`` names it."""

    def __init__(self, limit: int):
        if not 0 <= limit <= 1_000_000:
            raise FieldError("sync_error_limit", f"must be in [0, 1000000], got {limit}")
        self.limit = limit
        self.count = 0
        self.missed = 0                  # held setpoints since the count last was 0
        self.silent = 0                  # cycles in a row without any command
        self.tripped = ""                 # why, from the cycle it tripped on
        self.cause = TripCause.NONE

    def update(self, missed: bool, arrived: bool = True) -> bool:
        self.silent = 0 if arrived else self.silent + 1
        if missed:
            self.count += MISS_WEIGHT
            self.missed += 1
        else:
            self.count = max(0, self.count - ON_TIME_CREDIT)
            if self.count == 0:
                self.missed = 0
        if self.limit and not self.tripped and self.count > self.limit:
            count = (f"sync error count {self.count} > sync_error_limit {self.limit} ({self.missed} held "
                     f"setpoints since the count last was 0; +{MISS_WEIGHT} per held setpoint, "
                     f"-{ON_TIME_CREDIT} per fresh one)")
            # silent: no command for as many cycles as the limit lets pass in a row
            if missed and self.silent >= self.limit // MISS_WEIGHT:
                self.cause = TripCause.WATCHDOG
                self.tripped = f"no drives/command for the last {self.silent} cycles: {count}"
            else:
                self.cause = TripCause.DEADLINE_MISSED
                self.tripped = f"commands missed the plant's cycle: {count}"
            return True
        return False


class SetpointHold:
    """The drives' zero-order hold in realtime mode: the latest command they got and its
    stamp, whether any command came since the last tick, and the sync error counter
    over the ticks. sim_hw ``latch``-es each applicable command, calls ``command_came``
    for any decoded one, and ``tick`` at each period.

    The answer to the state last published is the setpoint of the next tick whatever
    else comes (nothing newer can: the controller answers states it has), so the plant
    may integrate on it as soon as it arrives and leave the tick only the publishing:
    ``latch`` says when."""

    def __init__(self, n_drives: int, sync_error_limit: int):
        self.effort, self.stamp_ns = [0.0] * n_drives, -1
        self.arrived = False
        self.applied = False             # the fresh answer of this period was stepped on at arrival
        self.sync = SyncErrorCounter(sync_error_limit)

    def command_came(self) -> None:
        self.arrived = True

    def latch(self, effort, stamp_ns: int, published_ns: int | None = None) -> bool:
        """The latest command; True when it is the first answer to the state published
        as ``published_ns``: the plant steps on it now, and the tick will not."""
        self.effort, self.stamp_ns = effort, stamp_ns
        if stamp_ns == published_ns and not self.applied:
            self.applied = True
            return True
        return False

    def tick(self, now_ns: int) -> tuple[list, int | None, bool]:
        """At the tick of the state stamped ``now_ns``: (the effort to apply, None when
        ``latch`` had it applied already; the stamp of the command applied again when it
        does not answer that state (a miss; None: a fresh setpoint); whether the sync
        error counter trips on this tick)."""
        held = None if self.stamp_ns == now_ns else self.stamp_ns
        arrived, self.arrived = self.arrived, False
        effort, self.applied = None if self.applied else self.effort, False
        return effort, held, self.sync.update(held is not None, arrived)

