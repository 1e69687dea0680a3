"""G-code programs -> segments -> a validated trajectory (feed, scaling, repetition)."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.task_space import PLANAR, POSITION, SPATIAL
from pkm_trajectory.planner import Arc, Dwell, Limits, Line, plan, validate
from pkm_trajectory.program import gcode_segments

ARCHI = load_machine("archi").model
LIMITS = Limits(velocity=(0.5, 0.5, 2.0), acceleration=(5.0, 5.0, 20.0), jerk=(200.0, 200.0, 800.0))
START = (1.0, -0.4, math.pi / 4)

SQUARE = """
G21 G90 G17          (mm, absolute)
G1 F600 X1050 Y-400  ; 10 mm/s
G3 X1050 Y-350 I0 J25
G1 X1000 C90
G4 P0.2
G0 X1000 Y-400 C45
M2
"""


def test_program_to_segments_and_a_valid_trajectory():
    segs = gcode_segments(SQUARE, space=PLANAR, start_pose=START)
    assert [type(s) for s in segs] == [Line, Arc, Line, Dwell, Line]
    assert segs[0].end == (1.05, -0.4, math.pi / 4) and segs[0].speed == pytest.approx(0.01)
    arc = segs[1]
    assert arc.center == pytest.approx((1.05, -0.375)) and arc.sweep == pytest.approx(math.pi)
    assert segs[2].end[2] == pytest.approx(math.pi / 2)
    s = plan(segs, LIMITS, translation_axes=2)
    np.testing.assert_allclose(s.position[-1], START, atol=1e-12)
    validate(s, ARCHI, joint_velocity_limit=1.0, max_condition=50.0)


def test_feed_override_scaling_and_repetition():
    base = gcode_segments(SQUARE, space=PLANAR, start_pose=START)
    fast = gcode_segments(SQUARE, space=PLANAR, start_pose=START, feed_override=2.0)
    assert fast[0].speed == pytest.approx(2 * base[0].speed)
    big = gcode_segments(SQUARE, space=PLANAR, start_pose=START, scale=2.0)
    assert big[0].end[0] == pytest.approx(1.1) and big[1].r == pytest.approx(0.05)
    three = gcode_segments(SQUARE, space=PLANAR, start_pose=START, repeat=3)
    assert len(three) == 3 * len(base)
    with pytest.raises(ValueError, match="feed_override: must be in"):
        gcode_segments(SQUARE, space=PLANAR, start_pose=START, feed_override=2.5)
    with pytest.raises(ValueError, match="repeat: the program ends at"):
        gcode_segments("G1 F60 X1010\nM2", space=PLANAR, start_pose=START, repeat=2)


def test_axes_per_machine_kind():
    with pytest.raises(ValueError, match=r"line 1: this machine has no Z axis \(Z5 mm\): its task coordinates are "
                                         r"x, y, theta \(G-code X Y C\)"):
        gcode_segments("G1 F60 Z5", space=PLANAR, start_pose=START)
    with pytest.raises(ValueError, match="line 1: this machine has no C axis: its task coordinates are x, y, z"):
        gcode_segments("G1 F60 C5", space=POSITION, start_pose=(0.0, 0.0, 0.8))
    with pytest.raises(ValueError, match="line 2: this machine has no A axis"):
        gcode_segments("G1 F60 X1\nG1 A5", space=PLANAR, start_pose=START)
    with pytest.raises(ValueError, match=r"start_pose: expected 6 task coordinates \(x, y, z, a, b, c\)"):
        gcode_segments("G1 F60 X1", space=SPATIAL, start_pose=(0.0, 0.0, 0.8))
    segs = gcode_segments("G91 G1 F60 Z-10", space=POSITION, start_pose=(0.0, 0.0, 0.8))
    assert segs[0].end == pytest.approx((0.0, 0.0, 0.79))


def test_program_with_blending_joins_at_rest_and_stays_valid():
    from pkm_trajectory.planner import plan_with_blending
    segs = gcode_segments(SQUARE, space=PLANAR, start_pose=START)
    exact = plan(segs, LIMITS, translation_axes=2)
    blended = plan_with_blending(segs, LIMITS, 1e-4, translation_axes=2)
    assert np.all(np.diff(blended.time_s) > 0)
    np.testing.assert_allclose(blended.position[-1], START, atol=1e-12)
    assert blended.duration_s <= exact.duration_s + 1e-9
    assert np.all(np.abs(blended.acceleration) <= np.array(LIMITS.acceleration) * (1 + 1e-6))
    validate(blended, ARCHI, joint_velocity_limit=1.0, max_condition=50.0)


def test_full_circle_after_an_arc_is_a_full_circle():
    """Round-off in an arc's end must not turn the next full circle into nothing."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        r1, r2 = rng.uniform(5, 30, 2)
        text = (f"G21 G90 G1 F600 X1000 Y-400\nG2 X{1000 + 2 * r1:.4f} Y-400 I{r1:.4f} J0\n"
                f"G3 X{1000 + 2 * r1:.4f} Y-400 I{-r2:.4f} J0\nM2")
        segs = gcode_segments(text, space=PLANAR, start_pose=START)
        assert segs[-1].sweep == pytest.approx(2 * math.pi)
        assert abs(segs[-2].sweep) == pytest.approx(math.pi)


def test_zero_moves_and_zero_dwells_are_dropped():
    segs = gcode_segments("G21 G90 G1 F600 X1000 Y-400\nG4 P0\nG1 X1010\nM2", space=PLANAR, start_pose=START)
    s = plan(segs, LIMITS, translation_axes=2)
    assert np.all(np.diff(s.time_s) > 0)


def test_g64_blends_its_corners_within_p_and_g61_stops_at_its_own():
    """A square under G64 P0.5 (mm) then the same square under G61, planned with the
    node's default blending off: the G64 corners are passed moving, the path within
    0.5 mm of the programmed one (planner._deviation); the G61 corners are reached at
    rest, and so is the start point where the mode changes."""
    from pkm_trajectory.planner import _deviation, plan_with_blending
    square = "X50 Y0\nX50 Y50\nX0 Y50\nX0 Y0\n"
    limits = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))
    segments = gcode_segments(f"G21 G90 G1 F3000\nG64 P0.5\n{square}G61\n{square}M2", space=POSITION,
                              start_pose=(0.0, 0.0, 0.0))
    s = plan_with_blending(segments, limits, 0.0, rate_hz=2000.0)
    speed = np.linalg.norm(s.velocity[:, :2], axis=1)
    at_start = np.flatnonzero((np.linalg.norm(s.position[:, :2], axis=1) < 1e-12) & (speed < 1e-12))
    join = at_start[(at_start > 10) & (at_start < len(speed) - 10)]
    assert len(join), "no stop at the start point between the G64 and the G61 square"
    g64, g61 = slice(0, join[0]), slice(join[-1], None)
    path = [(0.0, 0.0), (0.05, 0.0), (0.05, 0.05), (0.0, 0.05), (0.0, 0.0), (0.05, 0.0)]
    for k in range(1, 4):
        prev, corner, nxt = (np.array(path[k + d]) for d in (-1, 0, 1))
        d = np.linalg.norm(s.position[g64, :2] - corner, axis=1)
        near = d < 2e-3
        deviation = max(_deviation(p, prev, corner, nxt) for p in s.position[g64, :2][near])
        assert 1e-5 < d.min() and deviation <= 5e-4 * (1 + 1e-6) and speed[g64][d.argmin()] > 0.05
        d = np.linalg.norm(s.position[g61, :2] - corner, axis=1)
        assert d.min() < 1e-9 and speed[g61][d.argmin()] < 1e-9
    exact = plan_with_blending(gcode_segments(f"G21 G90 G1 F3000\nG61\n{square}{square}M2", space=POSITION,
                                              start_pose=(0.0, 0.0, 0.0)), limits, 0.0, rate_hz=2000.0)
    assert s.duration_s < exact.duration_s - 0.1


def test_a_six_axis_program_moves_every_task_coordinate_its_words_name():
    """X Y Z in mm and A B C in degrees onto (x, y, z, a, b, c); an angle not given
    keeps its value; G91 adds; an arc carries z and the angles linearly to its end;
    the size adjustment scales the translation only."""
    start = (0.0, 0.0, 0.5, 0.0, 0.0, 0.1)
    text = "G21 G90 G1 F600 X10 A5\nB-3 C20\nG91 Z-2 A1\nG90 G3 X0 Y10 I-10 J0 B0\nM2"
    segs = gcode_segments(text, space=SPATIAL, start_pose=start)
    deg = math.radians
    assert segs[0].end == pytest.approx((0.010, 0.0, 0.5, deg(5), 0.0, 0.1))
    assert segs[1].end == pytest.approx((0.010, 0.0, 0.5, deg(5), deg(-3), deg(20)))
    assert segs[2].end == pytest.approx((0.010, 0.0, 0.498, deg(6), deg(-3), deg(20)))
    arc = segs[3]
    assert arc.end == pytest.approx((0.0, 0.010, 0.498, deg(6), 0.0, deg(20)), abs=1e-15)
    assert arc.point(0.5) == pytest.approx([0.010 * math.cos(math.pi / 4), 0.010 * math.sin(math.pi / 4), 0.498,
                                            deg(6), deg(-1.5), deg(20)])
    big = gcode_segments(text, space=SPATIAL, start_pose=start, scale=2.0)
    assert big[2].end == pytest.approx((0.020, 0.0, 0.496, deg(6), deg(-3), deg(20)))


def test_a_program_that_leaves_the_workspace_is_refused_with_its_line():
    """G1 X2000 on ARCHI was planned (joint limits only) and travelled ~420 mm to
    x = 1.42 m before the controller's workspace trip; an arc bulging out of the box
    is refused too, and a hexapod's angle past its range."""
    from pkm_trajectory.planner import PlanBudget, TrajectoryRejected, plan_validated
    from pkm_kinematics.analysis import task_box
    home = [float(v) for v in ARCHI.home]
    for text, words in (("G1 F600 X1050\nG1 X2000\n", "line 2: x would reach 2, outside the workspace [0.6, 1.4]"),
                        # from y = -0.4 a half circle of radius 0.1 to the +y side reaches y = -0.2
                        ("G1 F600 Y-400\nG2 X1000 Y-400 I0 J100\n", "line 2: y would reach -0.2")):
        with pytest.raises(TrajectoryRejected, match=words.replace("[", r"\[").replace("]", r"\]")):
            plan_validated(gcode_segments(text, PLANAR, home), ARCHI, LIMITS, 1000.0, budget=PlanBudget())
    hexapod = load_machine("hexapod8").model
    lo, hi = task_box(hexapod)[3]
    assert hi - lo < 2.0                                               # a's range about home, in rad
    with pytest.raises(TrajectoryRejected, match=r"line 1: a would reach"):
        plan_validated(gcode_segments(f"G1 F600 A{math.degrees(hi) + 5:.3f}\n", SPATIAL, list(hexapod.home)),
                       hexapod, Limits(velocity=(0.5,) * 6, acceleration=(5.0,) * 6, jerk=(200.0,) * 6), 1000.0)
