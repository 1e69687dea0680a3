"""Lockstep bookkeeping of the controller node (pure, no rclpy): which drive state is
answered when, and when silence is a fault.

In lockstep the plant publishes the drive state of step k and waits for the command
stamped k. A metrology strategy also needs the Gough reading of the same instant
(``metrology/struts`` for sensor_space, MoM3 §6.4; ``metrology/pose`` for
measured_space, §6.3), which travels through another process and may arrive before
or after its state. ``StampPairing`` keeps the readings by stamp and the one state
that waits for its reading; it also recognises the plant's repeats of a state
(sim_hw republishes step 0 until the graph is connected) and names the silence that
must stop the machine.
"""

from __future__ import annotations

from pkm_common.watchdog import SilenceWatchdog

__all__ = ["StampPairing"]

KEEP_READINGS_NS = 100_000_000      # readings no state asked for: the last 0.1 s are kept
PRUNE_ABOVE = 8                     # ... once more than this many are held
OWN_STALL_S = 0.1                   # a watchdog check this late means this process was stalled


class StampPairing:
    """Pairs each drive state with the metrology reading of its stamp.

    ``needs_reading``: the strategy closes its loop on the metrology (``reading`` names
    the stream in fault messages: 'struts' or 'pose'). Times are wall-clock seconds
    (``time.monotonic``); stamps are integer nanoseconds.
    """

    def __init__(self, needs_reading: bool, reading: str = ""):
        self.needs_reading = needs_reading
        self.reading = reading
        self.readings: dict[int, object] = {}
        self.pending = None            # the state (with .stamp_ns) waiting for its reading
        self.last_answered_ns: int | None = None
        self.steps = 0                 # distinct states arrived
        self.state_watchdog = SilenceWatchdog(OWN_STALL_S)

    def reset_watchdog(self) -> None:
        """Disarm the watchdog until the next state (activation)."""
        self.state_watchdog.disarm()

    def state_arrived(self, stamp_ns: int, now_s: float) -> bool:
        """A drive state arrived at ``now_s``: False for a repeat of the stamp last
        answered (nothing to do), True for a new step (it is counted as answered).
        Once the loop runs only a new step feeds the watchdog (armed from the first):
        the plant repeats a state it has no answer for, and a repeat must not hide a
        silent metrology. The repeats of the first state do feed it: until the graph
        is connected, its reading may be lost to discovery (the sensor answers a
        repeat again)."""
        if stamp_ns == self.last_answered_ns:
            if self.steps == 1:
                self.state_watchdog.feed(now_s)
            return False
        self.state_watchdog.feed(now_s)
        self.last_answered_ns = stamp_ns
        self.steps += 1
        return True

    def wait_for_reading(self, state) -> bool:
        """True when ``state`` (prepared) must wait for its reading: it is kept as the
        pending state and answered by :meth:`reading_arrived`."""
        if self.needs_reading and state.stamp_ns not in self.readings:
            self.pending = state
            return True
        return False

    def reading_arrived(self, stamp_ns: int, reading):
        """Keep ``reading``; returns the pending state it completes (then no longer
        pending), or None."""
        readings = self.readings
        if len(readings) > PRUNE_ABOVE:
            self.readings = readings = {s: r for s, r in readings.items() if s > stamp_ns - KEEP_READINGS_NS}
        readings[stamp_ns] = reading
        pending = self.pending
        if pending is not None and pending.stamp_ns == stamp_ns:
            self.pending = None
            return pending
        return None

    def take_reading(self, stamp_ns: int):
        """The reading of ``stamp_ns`` (forgotten), or None."""
        return self.readings.pop(stamp_ns, None)

    def silence_fault(self, now_s: float, state_timeout_s: float, reading_timeout_s: float) -> str | None:
        """Why the machine must stop at ``now_s``, or None: a pending state whose reading
        has not come within ``reading_timeout_s``, or no drive state for
        ``state_timeout_s``. Silent before the first state (the plant only repeats
        step 0 for discovery until the run starts).

        Call it periodically. A call more than ``OWN_STALL_S`` after the previous one
        means this process itself did not run: that gap is not counted as the plant's
        silence (pkm_common.watchdog; a test graph in one executor tripped while the
        trajectory node planned for 0.6 s)."""
        silent = self.state_watchdog.silence_s(now_s)
        if silent is None:
            return None
        if self.pending is not None:
            if silent > reading_timeout_s:
                return (f"metrology/{self.reading}: nothing for the state of {self.pending.stamp_ns * 1e-9:.3f} s "
                        f"within {reading_timeout_s:g} s")
            return None
        if silent > state_timeout_s:
            return f"drives/state: none for {state_timeout_s:g} s"
        return None
