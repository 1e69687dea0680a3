"""StampPairing: each drive state answered once, with the metrology of its own stamp."""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_controller.lockstep import KEEP_READINGS_NS, StampPairing

MS = 1_000_000


def _state(k: int):
    return SimpleNamespace(stamp_ns=k * MS)


def test_a_repeated_state_is_not_answered_twice():
    pairing = StampPairing(needs_reading=False)
    assert pairing.state_arrived(0, 1.0)
    assert not pairing.state_arrived(0, 1.1)       # sim_hw's discovery repeats of step 0
    assert pairing.state_arrived(MS, 1.2)
    assert not pairing.wait_for_reading(_state(1))  # an encoder strategy never waits


def test_a_state_waits_for_its_reading_and_the_reading_completes_it():
    pairing = StampPairing(needs_reading=True, reading="struts")
    state = _state(3)
    assert pairing.state_arrived(state.stamp_ns, 0.0)
    assert pairing.wait_for_reading(state)
    assert pairing.reading_arrived(2 * MS, "old") is None      # another stamp: kept, not answered
    assert pairing.reading_arrived(3 * MS, "mine") is state
    assert pairing.pending is None
    assert pairing.take_reading(3 * MS) == "mine" and pairing.take_reading(3 * MS) is None


def test_a_reading_that_came_first_lets_its_state_go_straight_on():
    pairing = StampPairing(needs_reading=True, reading="pose")
    assert pairing.reading_arrived(5 * MS, "early") is None
    assert not pairing.wait_for_reading(_state(5))
    assert pairing.take_reading(5 * MS) == "early"


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 400), min_size=1, max_size=60))
def test_readings_nobody_asked_for_are_forgotten_after_a_tenth_of_a_second(steps):
    pairing = StampPairing(needs_reading=True)
    for k in steps:
        pairing.reading_arrived(k * MS, k)
    last = steps[-1] * MS
    kept = set(pairing.readings)
    assert last in kept
    assert len(kept) <= 9 or all(s > last - KEEP_READINGS_NS for s in kept)


def _checks(pairing, start_s, end_s, period_s=0.01, state_timeout_s=0.5, reading_timeout_s=0.2):
    """The watchdog called every ``period_s`` from start to end: the first fault and its time."""
    for k in range(round((end_s - start_s) / period_s) + 1):
        t = start_s + k * period_s
        fault = pairing.silence_fault(t, state_timeout_s, reading_timeout_s)
        if fault:
            return fault, round(t, 3)
    return None, None


def test_silence_is_a_fault_only_after_the_first_state_and_names_what_is_missing():
    pairing = StampPairing(needs_reading=True, reading="struts")
    assert _checks(pairing, 0.0, 5.0) == (None, None)                 # not armed before the first state
    pairing.state_arrived(0, 5.0)
    assert _checks(pairing, 5.01, 6.0) == ("drives/state: none for 0.5 s", 5.51)
    pairing.state_arrived(MS, 6.0)
    pairing.wait_for_reading(_state(1))
    assert _checks(pairing, 6.01, 7.0) == ("metrology/struts: nothing for the state of 0.001 s within 0.2 s", 6.21)
    pairing.reset_watchdog()
    assert _checks(pairing, 7.01, 9.0) == (None, None)


def test_a_stall_of_its_own_process_is_not_counted_as_the_plants_silence():
    pairing = StampPairing(needs_reading=False)
    pairing.state_arrived(0, 10.0)
    assert _checks(pairing, 10.0, 10.3) == (None, None)              # 0.3 s of silence counted
    # the executor was busy 0.6 s with another node's work: the next check comes late,
    # with the states still queued; the gap is not blamed on the plant
    assert pairing.silence_fault(10.9, 0.5, 0.2) is None
    # a plant that really went silent is still caught: 0.3 s before the stall + 0.2 s after
    assert _checks(pairing, 10.91, 12.0) == ("drives/state: none for 0.5 s", 11.11)


def test_repeated_stalls_delay_a_trip_but_never_prevent_it():
    pairing = StampPairing(needs_reading=False)
    pairing.state_arrived(0, 0.0)
    t, fault = 0.0, None
    while fault is None and t < 10.0:        # 0.15 s stalled, then 0.15 s of regular checks
        t += 0.15
        fault = pairing.silence_fault(t, 0.5, 0.2) or _checks(pairing, t + 0.01, t + 0.15)[0]
        t += 0.15
    assert fault == "drives/state: none for 0.5 s" and 0.5 < t < 1.5     # later than 0.5 s, but caught


def test_repeats_feed_the_watchdog_only_while_the_first_state_waits():
    """Discovery may lose the first reading (the plant repeats step 0 until answered):
    those repeats keep the watchdog quiet. Later a repeat of a pending state does not:
    a silent Gough trips within metrology_timeout_s."""
    from pkm_controller.lockstep import StampPairing

    class State:
        def __init__(self, stamp_ns):
            self.stamp_ns = stamp_ns
    pairing = StampPairing(True, "struts")
    assert pairing.state_arrived(0, 0.0) and pairing.wait_for_reading(State(0))
    for k in range(1, 20):                      # step 0 repeated every 0.05 s for 0.95 s
        assert not pairing.state_arrived(0, 0.05 * k)
        assert pairing.silence_fault(0.05 * k, 0.5, 0.5) is None
    assert pairing.reading_arrived(0, "reading") is not None
    assert pairing.state_arrived(1_000_000, 1.0) and pairing.wait_for_reading(State(1_000_000))
    fault = None
    for k in range(1, 20):                      # step 1 repeated, its reading never comes
        assert not pairing.state_arrived(1_000_000, 1.0 + 0.05 * k)
        fault = fault or pairing.silence_fault(1.0 + 0.05 * k, 0.5, 0.5)
    assert fault and fault.startswith("metrology/struts: nothing for the state of 0.001 s")
