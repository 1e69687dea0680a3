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


def test_silence_is_a_fault_only_after_the_first_state_and_names_what_is_missing():
    pairing = StampPairing(needs_reading=True, reading="struts")
    assert pairing.silence_fault(100.0, 0.5, 0.2) is None           # not armed before the first state
    pairing.state_arrived(0, 10.0)
    assert pairing.silence_fault(10.4, 0.5, 0.2) is None
    assert pairing.silence_fault(10.6, 0.5, 0.2) == "drives/state: none for 0.5 s"
    pairing.state_arrived(MS, 11.0)
    pairing.wait_for_reading(_state(1))
    assert pairing.silence_fault(11.1, 0.5, 0.2) is None
    assert pairing.silence_fault(11.3, 0.5, 0.2) == "metrology/struts: nothing for the state of 0.001 s within 0.2 s"
    pairing.reset_watchdog()
    assert pairing.silence_fault(99.0, 0.5, 0.2) is None
