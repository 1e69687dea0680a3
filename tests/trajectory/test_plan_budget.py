"""A plan's size is known before it is sampled (planner.check_plan_size): a dwell, a slow
feed, repeats, too many segments and slow blending are refused in milliseconds with
their line, and memory stays flat. Before, `G4 P10000` and `F0.0001` each passed 3 GB
in under 31 s, `repeat: 10000` reached 2.1 GB before its refusal, 100,000 blended
segments were still planning after 150 s, and a 400-digit number ended in an
OverflowError."""

import math
import time
import tracemalloc

import pytest

from pkm_kinematics import load_machine
from pkm_trajectory.gcode import GcodeError
from pkm_trajectory.planner import Limits, PlanBudget, TrajectoryRejected, plan_validated
from pkm_trajectory.program import gcode_segments

ARCHI = load_machine("archi").model
LIMITS = Limits(velocity=(0.5, 0.5, 2.0), acceleration=(5.0, 5.0, 20.0), jerk=(200.0, 200.0, 800.0))
START = [float(v) for v in ARCHI.home]
BUDGET = PlanBudget()                          # trajectory_node's defaults: 200,000 points at 1 kHz = 200 s


def refused(text: str, budget: PlanBudget = BUDGET, repeat: int = 1, blend: float = 0.0):
    """The refusal of ``text`` planned as trajectory_node does, its wall time and the
    peak of Python's allocations meanwhile."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises((TrajectoryRejected, GcodeError)) as info:
            segments = gcode_segments(text, ARCHI.task_space, START, repeat=repeat)
            plan_validated(segments, ARCHI, LIMITS, 1000.0, blend, budget=budget)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return str(info.value), time.perf_counter() - start, peak


@pytest.mark.parametrize("text, words", [
    ("G4 P10000\n", "line 1: a dwell of 10000 s exceeds max_points 200000 (200 s at 1000 Hz)"),
    ("G4 P1000000\n", "line 1: a dwell of 1e+06 s"),
    ("G1 F0.0001 X1001\n", "line 1: one move takes"),                  # 1 mm at 0.0001 mm/min
    ("G1 F600 X1001\nG4 P150\nG4 P150\n", "the plan takes 300.1"),     # together too long
])
def test_a_plan_too_long_is_refused_before_it_is_sampled(text, words):
    message, wall_s, peak = refused(text)
    assert words in message, message
    # sampling 10^4..10^6 s at 1 kHz took seconds and gigabytes; counting takes neither
    # (memory, a count: the wall time of a loaded machine is no measure here)
    assert peak < 20e6, (wall_s, peak)


def test_a_repeated_program_is_refused_by_its_segment_count_at_once():
    square = "G91 G1 F6000 X10\nY10\nX-10\nY-10\n"
    message, wall_s, peak = refused(square, repeat=10_000)
    assert "40000 segments exceed max_segments 10000" in message, message
    assert peak < 50e6, (wall_s, peak)
    # 2,500 repeats fit the count; their 2,500 x 4 moves are timed once each, then refused on time
    message, wall_s, _ = refused(square, repeat=2_500)
    assert "the plan takes" in message and "exceeds max_points" in message, message


def test_blending_stops_at_its_planning_time():
    zigzag = "G91 G64 P0.1 G1 F6000\n" + "X2\nY2\nX-2\nY-2\n" * 1_000       # 4,000 corners, in a 2 mm square
    budget = PlanBudget(max_planning_s=0.3)
    message, wall_s, _ = refused(zigzag, budget, blend=0.0)
    assert "blending its corner passed the planning time limit" in message and message.startswith("line "), message
    # stopped at the limit, not after the 4,000 corners (minutes): one corner past it
    assert "corner " in message and "of 3999)" in message, message


@pytest.mark.parametrize("text, words", [
    ("G4 P" + "9" * 400 + "\n", "line 1: P9999999999"),
    ("G1 F600 X1e999\n", "E999: unsupported word E"),                 # no exponent in G-code
    ("G1 F600 X" + "1" * 330 + "\n", "number out of range (330 characters)"),
])
def test_numbers_beyond_a_float_are_refused_with_their_line(text, words):
    with pytest.raises(GcodeError) as info:
        gcode_segments(text, ARCHI.task_space, START)
    assert words in str(info.value) and "line 1" in str(info.value), str(info.value)


def test_a_plan_inside_the_budget_is_unchanged():
    text = "G1 F600 X1050\nG4 P0.5\nG1 X1000\n"
    segments = gcode_segments(text, ARCHI.task_space, START)
    with_budget = plan_validated(segments, ARCHI, LIMITS, 1000.0, budget=BUDGET)
    without = plan_validated(segments, ARCHI, LIMITS, 1000.0)
    assert (with_budget.position == without.position).all()
    assert with_budget.duration_s == pytest.approx(without.duration_s) and with_budget.duration_s > 10.0
    # its segments know their lines
    assert [s.line for s in segments] == [1, 2, 3]


def test_the_budget_is_checked():
    for kwargs, words in (({"max_points": 1}, "max_points: must be an integer >= 2"),
                          ({"max_segments": 1.5}, "max_segments: must be an integer >= 1"),
                          ({"max_planning_s": math.inf}, "max_planning_s: must be in (0, inf) s")):
        with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
            PlanBudget(**kwargs)
