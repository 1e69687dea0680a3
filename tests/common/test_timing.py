"""DurationHistogram: quantiles within half a bin of numpy's, constant memory. Cadence:
periodic work in the cycle, the timer only as a fallback."""

import math

import numpy as np

import pytest

from pkm_common.timing import Cadence, DurationHistogram, percentiles_us


def test_quantiles_match_numpy_within_half_a_bin():
    rng = np.random.default_rng(3)
    samples = rng.lognormal(mean=math.log(150e-6), sigma=0.6, size=20000)
    h = DurationHistogram()
    for s in samples:
        h.add(float(s))
    for q in (0.5, 0.9, 0.99):
        exact = float(np.quantile(samples, q))
        assert abs(h.quantile_s(q) / exact - 1.0) < 0.011
    assert h.count == 20000 and h.max_s == samples.max()
    assert percentiles_us("c", h)["c_us_p50"] == h.quantile_s(0.5) * 1e6


def test_memory_does_not_grow_with_the_samples():
    h = DurationHistogram()
    size = len(h.counts)
    for k in range(100000):
        h.add(1e-6 * (k % 997 + 1))
    assert len(h.counts) == size and len(h) == 100000 and sum(h.counts) == 100000
    assert math.isnan(DurationHistogram().quantile_s(0.5))
    h.add(math.nan)                     # ignored
    h.add(1e6)                          # beyond the last bin: counted there, the max exact
    assert h.max_s == 1e6 and h.quantile_s(1.0) == 1e6


def test_cadence_does_the_work_in_the_cycle_and_the_timer_only_when_no_cycle_runs():
    now = [0.0]
    c = Cadence(100, clock=lambda: now[0])          # a clock in ms: exact sums
    done = []
    # a loop at 1 kHz for 1 s, and a 0.1 s timer of another phase (at 37 + 100 k ms)
    for k in range(1000):
        now[0] = k
        if c.in_cycle():
            done.append(("cycle", k))
        if k % 100 == 37 and c.on_timer():
            done.append(("timer", k))
    assert {kind for kind, _ in done} == {"cycle"} and len(done) == 10
    gaps = np.diff([k for _, k in done])
    assert (gaps == 100).all()
    # the loop stopped: the timer takes over, each time two periods after the last work
    last, timer = done[-1][1], []
    for k in range(10, 17):
        now[0] = 37 + 100 * k
        if c.on_timer():
            timer.append(37 + 100 * k)
    assert last == 900 and timer == [1137, 1337, 1537]
    with pytest.raises(ValueError, match="period_s"):
        Cadence(0.0)
