"""RateLimit: at most count events a window, the rest counted."""

import pytest

from pkm_common.ratelimit import RateLimit


def test_at_most_count_a_window_and_the_rest_counted():
    limit = RateLimit(2, 1.0)
    assert [limit.allow(t) for t in (0.0, 0.1, 0.2, 0.9)] == [True, True, False, False]
    assert limit.allow(1.0) and limit.suppressed == 2
    with pytest.raises(ValueError, match="count must be >= 1"):
        RateLimit(0)
