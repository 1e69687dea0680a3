"""The planner's core on six task coordinates (issue 23: 6-DOF trajectories with
Ruckig): a move of LinuxCNC's genhexkins hexapod in x, y, z and its A, B, C angles,
timed and sampled by the same time law as the 3-DOF machines'. References: the
limits, finite differences of the samples, and the hexapod's strut lengths and
task Jacobian along them."""

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_trajectory.planner import Limits, Line, plan

LIMITS = Limits(velocity=(0.2, 0.2, 0.1, 0.5, 0.5, 1.0), acceleration=(2.0, 2.0, 1.0, 4.0, 4.0, 6.0),
                jerk=(50.0, 50.0, 25.0, 100.0, 100.0, 150.0))


def test_a_six_axis_move_is_timed_within_every_axis_limit_and_ends_on_target():
    hexapod = load_machine("genhexkins").model
    start = tuple(hexapod.home)
    target = tuple(hexapod.home + np.array([0.05, -0.03, 0.02, 0.08, -0.05, 0.2]))
    samples = plan([Line(start, target), Line(target, start)], LIMITS, rate_hz=1000.0)
    assert samples.position.shape[1] == 6 and samples.velocity.shape[1] == 6
    np.testing.assert_array_equal(samples.position[-1], start)
    k = int(np.argmin(np.abs(samples.position - np.array(target)).sum(axis=1)))
    np.testing.assert_allclose(samples.position[k], target, atol=1e-12)           # stops on the corner
    assert (np.abs(samples.velocity) <= np.array(LIMITS.velocity) * (1 + 1e-9)).all()
    assert (np.abs(samples.acceleration) <= np.array(LIMITS.acceleration) * (1 + 1e-6)).all()
    # the rotation (0.2 rad of C at 1 rad/s) is the slowest axis: it sets the duration
    assert samples.duration_s > 2 * 0.2 / 1.0
    # velocities are the derivative of the positions
    fd = np.gradient(samples.position, samples.time_s, axis=0)
    np.testing.assert_allclose(fd[1:-1], samples.velocity[1:-1], atol=2e-3)
    # along the motion the struts stay in their limits, and their rates are J(x) x'
    q, ok = hexapod.inverse_kinematics_batch(samples.position)
    assert ok.all() and hexapod.within_joint_limits(q).all()
    rates = np.einsum("kij,kj->ki", np.array([hexapod.task_jacobian(x) for x in samples.position[::50]]),
                      samples.velocity[::50])
    np.testing.assert_allclose(rates[1:-1], np.gradient(q, samples.time_s, axis=0)[::50][1:-1], atol=2e-4)


def test_limits_of_another_length_are_refused_by_name():
    with pytest.raises(ValueError, match=r"limits.acceleration: expected 6 positive finite numbers"):
        Limits(velocity=(1.0,) * 6, acceleration=(1.0,) * 3, jerk=(1.0,) * 6)
    with pytest.raises(ValueError, match=r"limits.velocity: expected 3 positive finite numbers"):
        Limits(velocity=(1.0,) * 4, acceleration=(1.0,) * 4, jerk=(1.0,) * 4)


PROGRAM = """G21 G90 G64 P0.2
G1 F1200 X20 Y-10 Z520 A3 B-2
C5
G3 X-20 Y10 I-20 J10 B1
G1 X0 Y0 Z508 A0 B0 C0
M2
"""


def test_a_six_axis_program_is_planned_and_validated_on_the_hexapod_strut_rates_checked():
    """The path trajectory_node and the scenarios take (G-code with A B C -> segments ->
    plan_validated): the strut rates it checks are J(x) x' with the hexapod's task
    Jacobian, so a strut velocity limit just below the peak rate of finite differences
    of the strut lengths is refused naming a strut, and just above it is accepted."""
    from pkm_trajectory.planner import TrajectoryRejected, plan_validated
    from pkm_trajectory.program import gcode_segments
    hexapod = load_machine("genhexkins").model
    segments = gcode_segments(PROGRAM, hexapod.task_space, hexapod.home)
    samples = plan_validated(segments, hexapod, LIMITS, 1000.0, max_condition=50.0)
    np.testing.assert_array_equal(samples.position[-1], hexapod.home)
    assert np.ptp(samples.position, axis=0)[3:] == pytest.approx(np.radians([3.0, 3.0, 5.0]), rel=1e-9)
    q, _ = hexapod.inverse_kinematics_batch(samples.position)
    peak = np.abs(np.gradient(q, samples.time_s, axis=0)).max()
    plan_validated(segments, hexapod, LIMITS, 1000.0, joint_velocity_limit=peak * 1.01)
    with pytest.raises(TrajectoryRejected, match=r"leg j\d velocity .* m/s exceeds"):
        plan_validated(segments, hexapod, LIMITS, 1000.0, joint_velocity_limit=peak * 0.99)
    # the hexapod's own conditioning measure (rotations weighted by its size) bounds it
    worst = hexapod.condition_number_batch(samples.position).max()
    with pytest.raises(TrajectoryRejected, match="machine condition number"):
        plan_validated(segments, hexapod, LIMITS, 1000.0, max_condition=worst * 0.999)


def test_a_hexapod_path_past_a_strut_limit_is_refused_naming_the_strut():
    """The planner's joint-limit check on a strut machine names the strut and its
    limits (it said only "rejected": a strut machine had no check_joint_limits)."""
    from pkm_trajectory.planner import Limits, TrajectoryRejected, plan, point_to_point, validate
    machine = load_machine("hexapod8").model
    end = machine.home + [0.0, 0.0, 0.5, 0.0, 0.0, 0.0]        # past the workspace too: validate without it
    samples = plan([point_to_point(machine.home, end)], Limits(np.full(6, 0.5), np.full(6, 5.0), np.full(6, 100.0)))
    with pytest.raises(TrajectoryRejected, match=r"x = \[0\.0, 0\.0, 0\.\d+.*\]\): s\d: 0\.95\d+ m outside its "
                                                 r"limits \[\d\.\d+, 0\.950000\] m"):
        validate(samples, machine)
