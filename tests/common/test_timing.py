"""DurationHistogram: quantiles within half a bin of numpy's, constant memory."""

import math

import numpy as np

from pkm_common.timing import DurationHistogram, percentiles_us


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
    size = h.counts.nbytes
    for k in range(100000):
        h.add(1e-6 * (k % 997 + 1))
    assert h.counts.nbytes == size and len(h) == 100000
    assert math.isnan(DurationHistogram().quantile_s(0.5))
    h.add(math.nan)                     # ignored
    h.add(1e6)                          # beyond the last bin: counted there, the max exact
    assert h.max_s == 1e6 and h.quantile_s(1.0) == 1e6
