"""pkm_common.watchdog: silence without the process's own stalls (pure)."""

import pytest

from pkm_common.watchdog import SilenceWatchdog


def _check_every(watchdog, start_s, end_s, period_s=0.01):
    """Regular checks from start_s to end_s; the last silence."""
    t, silence = start_s, None
    while t <= end_s + 1e-12:
        silence = watchdog.silence_s(t)
        t += period_s
    return silence


def test_disarmed_until_fed_and_again_after_disarm():
    watchdog = SilenceWatchdog(own_stall_s=0.3)
    assert _check_every(watchdog, 0.0, 5.0) is None
    watchdog.feed(5.0)
    assert watchdog.silence_s(5.25) == pytest.approx(0.25)
    watchdog.disarm()
    assert _check_every(watchdog, 5.26, 9.0) is None


def test_silence_grows_with_regular_checks_and_a_feed_resets_it():
    watchdog = SilenceWatchdog(own_stall_s=0.3)
    watchdog.feed(1.0)
    assert _check_every(watchdog, 1.0, 2.5, period_s=0.1) == pytest.approx(1.5)
    watchdog.feed(2.55)
    assert watchdog.silence_s(2.6) == pytest.approx(0.05)


def test_a_late_check_does_not_count_the_gap_but_counts_the_silence_around_it():
    watchdog = SilenceWatchdog(own_stall_s=0.3)
    watchdog.feed(10.0)
    assert _check_every(watchdog, 10.0, 10.4, period_s=0.1) == pytest.approx(0.4)
    # the executor ran another node's callback for 1.2 s: that gap is not silence
    assert watchdog.silence_s(11.6) == pytest.approx(0.4)
    # 0.4 s before + 0.6 s after the stall: 1.0 s, as a plant that really went silent
    assert _check_every(watchdog, 11.7, 12.2, period_s=0.1) == pytest.approx(1.0)
    # a gap just under own_stall_s is an ordinary (slow) check: counted
    assert watchdog.silence_s(12.45) == pytest.approx(1.25)


def test_repeated_stalls_delay_the_trip_but_never_prevent_it():
    watchdog = SilenceWatchdog(own_stall_s=0.1)
    watchdog.feed(0.0)
    t, silence = 0.0, 0.0
    while silence <= 1.0 and t < 30.0:       # 0.5 s stalled, then 0.1 s of regular checks
        t += 0.5
        silence = max(watchdog.silence_s(t), _check_every(watchdog, t + 0.01, t + 0.1))
        t += 0.1
    assert silence > 1.0 and 3.0 < t < 10.0


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_a_bad_stall_threshold_is_refused_naming_it(bad):
    with pytest.raises(ValueError, match=r"own_stall_s: must be > 0 s"):
        SilenceWatchdog(own_stall_s=bad)
