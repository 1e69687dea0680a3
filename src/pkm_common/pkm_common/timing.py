"""Timing figures the nodes write into their JSON summaries (no rclpy)."""

from __future__ import annotations

import math
import time

import numpy as np

from pkm_kinematics.errors import FieldError

__all__ = ["Cadence", "DurationHistogram", "percentiles_us"]


class Cadence:
    """When a loop node does its periodic side work (markers, diagnostics, recording
    batches): right after its answer in a cycle, where it has the most slack before
    its next input, rather than on a timer of its own. A timer's phase drifts against
    the loop's, and each time it lands just before an input the work sits on the
    deadline's path: in real time at 1 kHz, sim_hw's 10 Hz markers (~250 us to build,
    serialize and publish) showed as misses at every 0.1 s of a run.

    ``in_cycle()``: True (and the period restarts) when ``period_s`` has passed since
    the work was last done. ``on_timer()``: the fallback for a timer of the same work,
    for when no cycle runs (before the start, after the end, a stopped loop): True only
    when the work has not been done for two periods, so a running loop's cycles keep
    the timer idle."""

    def __init__(self, period_s: float, clock=time.monotonic):
        if not period_s > 0.0:
            raise FieldError("period_s", f"must be > 0 s, got {period_s!r}")
        self.period_s, self._clock = period_s, clock
        self._last = -math.inf

    def in_cycle(self) -> bool:
        return self._due(self.period_s)

    def on_timer(self) -> bool:
        return self._due(2.0 * self.period_s)

    def _due(self, after_s: float) -> bool:
        now = self._clock()
        if now - self._last < after_s:
            return False
        self._last = now
        return True


class DurationHistogram:
    """Durations in constant memory, however long a run is: counts in logarithmic bins
    (``RELATIVE_WIDTH`` wide, from ``LOW_S`` to ``HIGH_S``; outside them the end bins),
    plus the exact count, sum and maximum. A quantile is its bin's geometric centre:
    within half a bin width (0.5 %) of the exact one."""

    LOW_S, HIGH_S, RELATIVE_WIDTH = 1e-7, 100.0, 0.01

    def __init__(self):
        self._log_width = math.log1p(self.RELATIVE_WIDTH)
        self._bins = math.ceil(math.log(self.HIGH_S / self.LOW_S) / self._log_width) + 1
        self._scale = 1.0 / self._log_width
        self.counts = [0] * self._bins          # a list: added to twice a control cycle (~0.4 us, numpy's ~0.8)
        self.count, self.total_s, self.max_s = 0, 0.0, 0.0

    def add(self, duration_s: float) -> None:
        """One duration (s); NaN is ignored."""
        if not duration_s >= 0.0:
            return
        k = int(math.log(duration_s / self.LOW_S) * self._scale) if duration_s > self.LOW_S else 0
        self.counts[k if k < self._bins else self._bins - 1] += 1
        self.count += 1
        self.total_s += duration_s
        if duration_s > self.max_s:
            self.max_s = duration_s

    def __len__(self) -> int:
        return self.count

    def quantile_s(self, q: float) -> float:
        """The q-quantile (0..1) in seconds; NaN when empty."""
        if not self.count:
            return math.nan
        k = int(np.searchsorted(np.cumsum(self.counts), q * self.count, side="left"))
        if k >= self._bins - 1:                 # the open-ended last bin
            return self.max_s
        centre = self.LOW_S * math.exp((k + 0.5) * self._log_width)
        return min(centre, self.max_s)


def percentiles_us(name: str, samples_s) -> dict:
    """{"<name>_us_p50": ..., "<name>_us_p99": ...} of durations given in seconds (a
    sequence or a DurationHistogram); NaN when there are none (a run that never cycled)."""
    if isinstance(samples_s, DurationHistogram):
        return {f"{name}_us_p50": samples_s.quantile_s(0.5) * 1e6, f"{name}_us_p99": samples_s.quantile_s(0.99) * 1e6}
    us = np.asarray(samples_s if len(samples_s) else [math.nan], dtype=float) * 1e6
    return {f"{name}_us_p50": float(np.percentile(us, 50)), f"{name}_us_p99": float(np.percentile(us, 99))}
