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
