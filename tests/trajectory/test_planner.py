"""Trajectory core: jerk-limited time law (Ruckig), arcs, sampling, validation."""

import dataclasses
import math

import numpy as np
import pytest
from ruckig import InputParameter, Ruckig, Trajectory

from pkm_kinematics import load_machine
from pkm_trajectory.planner import (Arc, Dwell, Limits, Line, TrajectoryRejected, plan, point_to_point,
                                    validate)

ARCHI = load_machine("archi").model
LIMITS = Limits(velocity=(0.5, 0.5, 2.0), acceleration=(5.0, 5.0, 20.0), jerk=(200.0, 200.0, 800.0))


def derivative(samples, values):
    return np.gradient(values, samples.time_s, axis=0)


def check_limits(samples, limits, tol=1e-6):
    assert np.all(np.abs(samples.velocity) <= np.array(limits.velocity) * (1 + tol))
    assert np.all(np.abs(samples.acceleration) <= np.array(limits.acceleration) * (1 + tol))
    jerk = derivative(samples, samples.acceleration)[2:-2]     # finite differences
    assert np.all(np.abs(jerk) <= np.array(limits.jerk) * 1.05)


def test_line_respects_limits_and_ends_exactly():
    seg = Line((1.0, -0.4, math.pi / 4), (1.1, -0.35, math.pi / 2))
    s = plan([seg], LIMITS, rate_hz=2000.0)
    check_limits(s, LIMITS)
    np.testing.assert_array_equal(s.position[-1], np.array(seg.end))
    np.testing.assert_allclose(s.velocity[-1], 0.0, atol=1e-12)
    # the velocity is the derivative of the position
    np.testing.assert_allclose(derivative(s, s.position)[5:-5], s.velocity[5:-5], atol=2e-3)


def test_one_axis_duration_is_ruckig_time_optimal():
    """A move along x alone takes exactly Ruckig's time-optimal duration for that axis."""
    s = plan([point_to_point((0.0, 0.0, 0.0), (0.2, 0.0, 0.0))], LIMITS)
    inp = InputParameter(1)
    inp.current_position, inp.target_position = [0.0], [0.2]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [0.5], [5.0], [200.0]
    ref = Trajectory(1)
    Ruckig(1).calculate(inp, ref)
    assert s.duration_s == pytest.approx(ref.duration, rel=1e-12)
    # bang-bang check: the velocity limit is reached on a long move
    assert np.abs(s.velocity[:, 0]).max() == pytest.approx(0.5, rel=1e-9)


def test_arc_stays_on_its_circle():
    arc = Arc(start=(0.1, 0.0, 0.0), center=(0.0, 0.0), sweep=math.pi, end_rest=(0.0,))
    s = plan([arc], LIMITS, rate_hz=2000.0)
    r = np.hypot(s.position[:, 0], s.position[:, 1])
    assert np.abs(r - 0.1).max() < 1e-6                     # within 1 um
    np.testing.assert_allclose(s.position[-1, :2], [-0.1, 0.0], atol=1e-12)
    check_limits(s, LIMITS)


def test_dwell_and_sequence():
    segs = [Line((0.0, 0.0, 0.0), (0.1, 0.0, 0.0)), Dwell((0.1, 0.0, 0.0), 0.25),
            Line((0.1, 0.0, 0.0), (0.1, 0.1, 0.0))]
    s = plan(segs, LIMITS)
    held = (s.time_s > plan(segs[:1], LIMITS).duration_s + 1e-9) & (s.time_s < plan(segs[:2], LIMITS).duration_s)
    assert held.sum() >= 240 and np.all(s.position[held] == [0.1, 0.0, 0.0])
    assert np.all(np.diff(s.time_s) > 0)


def test_archi_motion_rejected_for_a_sub_machine_accepted_for_the_machine():
    """ARCHI §4: a translation while the nacelle turns from pi/4 to pi/2 drives the
    3-leg sub-machine J_234 through its singularity; the 4-leg machine stays well
    conditioned and accepts it."""
    seg = Line((1.0, -0.6, math.pi / 4), (1.0, -0.7, math.pi / 2))
    s = plan([seg], LIMITS, rate_hz=500.0)
    validate(s, ARCHI, joint_velocity_limit=2.0, joint_acceleration_limit=50.0, max_condition=50.0)
    with pytest.raises(TrajectoryRejected, match=r"sub-machine J_234 condition number .* exceeds the bound 50"):
        validate(s, ARCHI, max_condition=50.0, legs=(1, 2, 3))


def test_validation_names_sample_and_limit():
    s = plan([Line((1.0, -0.4, 0.0), (1.0, -1.2, 0.0))], LIMITS, rate_hz=200.0)
    with pytest.raises(TrajectoryRejected, match=r"sample \d+ .* unreachable: leg q\d"):
        validate(s, ARCHI)
    fast = plan([Line((0.8, -0.4, 0.0), (1.2, -0.4, 0.0))], LIMITS, rate_hz=200.0)
    with pytest.raises(TrajectoryRejected, match=r"leg q\d velocity .* exceeds 0.1 m/s by"):
        validate(fast, ARCHI, joint_velocity_limit=0.1)
    with pytest.raises(ValueError, match="limits.velocity"):
        Limits((0.5, 0.0, 1.0), (1.0, 1.0, 1.0), (1.0, 1.0, 1.0))


def test_feed_caps_the_path_speed_and_orthoglide_bounds():
    seg = Line((0.0, 0.0, 0.0), (0.03, 0.04, 0.0), speed=0.1)
    s = plan([seg], LIMITS, translation_axes=3)
    speed = np.hypot(s.velocity[:, 0], s.velocity[:, 1])
    assert speed.max() == pytest.approx(0.1, rel=1e-9)
    ortho = load_machine("orthoglide").model
    inside = plan([Line((0.0, 0.0, 0.0), (0.05, 0.05, 0.05))], LIMITS)
    validate(inside, ortho, transmission_bounds=ortho.transmission_bounds)
    # beyond Q2 on the diagonal the factors leave [1/2, 2] (Orthoglide §4.4)
    outside = plan([Line((0.0, 0.0, 0.0), (0.16, 0.16, 0.16))], LIMITS)
    ortho_wide = ortho.with_legs("o", [dataclasses.replace(leg, joint_limits=(-1.0, 1.0)) for leg in ortho.legs])
    with pytest.raises(TrajectoryRejected, match=r"velocity transmission factor .* outside \[0.5, 2\]"):
        validate(outside, ortho_wide, transmission_bounds=ortho.transmission_bounds)


def test_blended_corners_stay_within_tolerance_and_limits():
    """A zig-zag of lines blended with a 0.5 mm tolerance: faster than exact stop, never
    beyond the acceleration or jerk limits (unlike LinuxCNC issue #3773), and every
    sample within the tolerance of the programmed path."""
    from pkm_trajectory.planner import _deviation, plan_blended
    pts = [(0.0, 0.0, 0.0), (0.05, 0.0, 0.0), (0.05, 0.05, 0.0), (0.1, 0.05, 0.0), (0.12, 0.0, 0.0)]
    lines = [Line(a, b) for a, b in zip(pts, pts[1:])]
    exact = plan(lines, LIMITS, rate_hz=4000.0)
    blended = plan_blended(lines, LIMITS, tolerance=5e-4, rate_hz=4000.0)
    assert blended.duration_s < 0.9 * exact.duration_s
    check_limits(blended, LIMITS)
    dev = [min(_deviation(p, pts[i], pts[i + 1], pts[i + 2]) for i in range(len(pts) - 2))
           for p in blended.position]
    assert max(dev) <= 5e-4 * (1 + 1e-6)
    np.testing.assert_array_equal(blended.position[-1], pts[-1])
    # zero tolerance is an exact stop at every corner
    none = plan_blended(lines, LIMITS, tolerance=0.0, rate_hz=4000.0)
    assert none.duration_s > blended.duration_s


@pytest.mark.parametrize("radius", [0.05, 0.002, 0.0005])
def test_small_and_anisotropic_arcs_respect_per_axis_limits(radius):
    """An arc's x and y rates peak somewhere on the sweep and its centripetal jerk grows
    like v^3/R^2: both are budgeted, per axis, also with very different x/y limits."""
    limits = Limits(velocity=(0.05, 0.5, 2.0), acceleration=(5.0, 5.0, 20.0), jerk=(200.0, 200.0, 800.0))
    arc = Arc(start=(radius, 0.0, 0.0), center=(0.0, 0.0), sweep=2 * math.pi, end_rest=(0.0,))
    s = plan([arc], limits, rate_hz=20000.0)
    check_limits(s, limits)


def test_a_move_to_the_current_pose_is_refused_cleanly():
    from pkm_trajectory.planner import TrajectoryRejected
    with pytest.raises(TrajectoryRejected, match="nothing to do"):
        plan([point_to_point((1.0, -0.4, 0.7), (1.0, -0.4, 0.7 + 1e-16))], LIMITS)


def test_random_blends_never_exceed_limits_or_tolerance():
    """Random 3-D zig-zags (jerk phases of neighbouring lines can coincide on an axis),
    sampled at 20 kHz: within the tolerance and every limit."""
    from pkm_trajectory.planner import _deviation, plan_blended
    rng = np.random.default_rng(11)
    for _ in range(6):
        pts = np.cumsum(rng.uniform(-0.03, 0.03, (5, 3)), axis=0)
        lines = [Line(tuple(a), tuple(b)) for a, b in zip(pts, pts[1:])]
        s = plan_blended(lines, LIMITS, tolerance=3e-4, rate_hz=20000.0)
        check_limits(s, LIMITS)
        dev = [min(_deviation(p, pts[i], pts[i + 1], pts[i + 2]) for i in range(len(pts) - 2)) for p in s.position]
        assert max(dev) <= 3e-4
