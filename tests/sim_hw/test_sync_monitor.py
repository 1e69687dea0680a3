"""The drives' sync error counter (ETG.1020 0x10F1:02): +3 per held setpoint, -1 per
fresh one, a fault once over the limit."""

import pytest

from pkm_sim_hw.sync_monitor import SetpointHold, SyncErrorCounter


def run(pattern: str, limit: int = 12) -> int | None:
    """The cycle index at which the counter trips on ``pattern`` (x: held, .: fresh)."""
    counter = SyncErrorCounter(limit)
    for i, c in enumerate(pattern):
        if counter.update(c == "x"):
            return i
    return None


def test_a_burst_up_to_the_limit_passes_one_more_held_setpoint_trips():
    assert run("xxxx" + "." * 50) is None            # 12: not over 12
    assert run("xxxxx") == 4                           # 15 > 12 at the fifth


def test_sustained_misses_trip_above_a_quarter_and_never_below():
    assert run("x..." * 2000) is None                 # 25 %: +3 -3 per four cycles, stays bounded
    assert run("x.." * 200) is not None               # 33 %: +1 per three cycles, grows
    assert run("xx.." * 200) is not None              # 50 %


def test_it_trips_once_and_says_why():
    counter = SyncErrorCounter(3)
    assert [counter.update(True) for _ in range(4)] == [False, True, False, False]
    assert "sync error count 6 > sync_error_limit 3 (2 held setpoints" in counter.tripped


def test_zero_turns_it_off_and_a_bad_limit_is_refused():
    assert run("x" * 1000, limit=0) is None
    with pytest.raises(ValueError, match=r"sync_error_limit: must be in \[0, 1000000\], got -1"):
        SyncErrorCounter(-1)


def test_a_silent_controller_is_named_as_such_a_late_one_as_late():
    late = SyncErrorCounter(12)
    assert not any(late.update(True, arrived=True) for _ in range(4))
    assert late.update(True, arrived=True) and str(late.cause) == "deadline_missed"
    assert late.tripped.startswith("commands missed the plant's cycle: sync error count 15")
    silent = SyncErrorCounter(12)
    assert not any(silent.update(True, arrived=False) for _ in range(4))
    assert silent.update(True, arrived=False) and str(silent.cause) == "watchdog"
    assert silent.tripped.startswith("no drives/command for the last 5 cycles")
    # late for a while, then silent: the count built up by late commands says late
    mixed = SyncErrorCounter(12)
    assert [mixed.update(True, arrived=a) for a in (True, True, True, False, False)][-1]
    assert str(mixed.cause) == "deadline_missed"


def test_a_controller_late_once_then_dead_is_named_silent():
    """One late answer (count 3), then nothing: the trip comes 4 cycles later and names
    the silence, which is what started it (review finding)."""
    counter = SyncErrorCounter(12)
    assert [counter.update(True, arrived=a) for a in (True, False, False, False, False)][-1]
    assert str(counter.cause) == "watchdog" and counter.tripped.startswith("no drives/command for the last 4 cycles")


def test_the_hold_applies_the_latest_command_and_names_it_when_it_is_late():
    """sim_hw's realtime zero-order hold: the answer to a tick's state is fresh; without
    it the latest command is applied again and named by its stamp; five such ticks with
    no command at all trip the counter as silence."""
    hold = SetpointHold(2, 12)
    hold.latch([1.0, 2.0], 0)
    assert hold.tick(0) == ([1.0, 2.0], None, False)
    hold.command_came()                              # an older command arrived: not an answer
    assert hold.tick(1_000_000) == ([1.0, 2.0], 0, False)
    results = [hold.tick(k * 1_000_000) for k in range(2, 6)]
    assert [r[1] for r in results] == [0] * 4 and results[-1][2]
    assert str(hold.sync.cause) == "watchdog"


def test_the_answer_to_the_published_state_is_applied_once_on_arrival():
    """The fresh answer is stepped on when it arrives (latch says so, once) and the tick
    then has nothing to apply; a late command (older stamp) is left to the tick, which
    applies it as a held setpoint."""
    hold = SetpointHold(2, 12)
    assert hold.latch([1.0, 2.0], 0, published_ns=0)
    assert not hold.latch([1.0, 2.0], 0, published_ns=0)      # a repeat: already applied
    assert hold.tick(0) == (None, None, False)
    assert not hold.latch([3.0, 4.0], 0, published_ns=1_000_000)   # late: for the tick
    assert hold.tick(1_000_000) == ([3.0, 4.0], 0, False)
    assert hold.latch([5.0, 6.0], 2_000_000, published_ns=2_000_000)
    assert hold.tick(2_000_000) == (None, None, False)
