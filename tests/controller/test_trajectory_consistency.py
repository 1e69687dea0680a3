"""reference.check_consistent: the trajectories a planner makes pass (every task space,
250 Hz and 1 kHz, through the message as the node reads it); a bogus one is refused
for what it is (issue 40: a 2 m/s trajectory was accepted and its trip was named
encoder_fault)."""

import numpy as np
import pytest

from pkm_common.cdr import decode_multidof_trajectory
from pkm_common.conversions import trajectory_msg
from pkm_controller.reference import Reference, check_consistent, reference_from_trajectory
from pkm_kinematics import load_machine
from pkm_trajectory.planner import Limits, Line, plan
from rclpy.serialization import serialize_message


def planned(machine: str, rate_hz: float, far: float) -> Reference:
    """A move from home by ``far`` on every task axis, planned and read back as the node does."""
    model = load_machine(machine).model
    space = model.task_space
    home = np.asarray(model.home, dtype=float)
    dof, ta = space.dof, space.translation_axes
    limits = Limits(tuple([0.5] * ta + [2.0] * (dof - ta)), tuple([5.0] * ta + [20.0] * (dof - ta)),
                    tuple([200.0] * ta + [800.0] * (dof - ta)))
    samples = plan([Line(tuple(home), tuple(home + far))], limits, rate_hz, translation_axes=ta)
    msg = trajectory_msg(space, samples.time_s, samples.position, samples.velocity, samples.acceleration)
    return reference_from_trajectory(decode_multidof_trajectory(serialize_message(msg)), space)


@pytest.mark.parametrize("machine", ["archi", "orthoglide", "hexapod8"])
@pytest.mark.parametrize("rate_hz", [250.0, 1000.0])
def test_what_the_planner_makes_passes(machine, rate_hz):
    check_consistent(planned(machine, rate_hz, 0.02))


def test_a_trajectory_at_2_m_s_from_rest_is_refused_as_a_velocity_step():
    t = np.arange(50) * 0.001
    x = np.column_stack((1.0 + 2.0 * t, -0.4 + 0 * t, 0 * t))
    v = np.column_stack((2.0 + 0 * t, 0 * t, 0 * t))
    with pytest.raises(ValueError, match=r"it starts moving \(point 0, task axis 0 at 2 per s\); a trajectory "
                                         r"starts and ends at rest"):
        check_consistent(Reference(t, x, v))


def test_positions_that_jump_while_the_velocities_say_still_are_refused_naming_the_point():
    t = np.arange(50) * 0.001
    x = np.column_stack((1.0 + 0 * t, -0.4 + 0 * t, 0 * t))
    x[20:, 1] += 0.002                                          # 2 mm in one step, at rest
    with pytest.raises(ValueError, match=r"point 20 \(t = 0.0200 s\), task axis 1: its position changes by 0.002 "
                                         r"where its velocities give 0: not a motion"):
        check_consistent(Reference(t, x))
    good = planned("archi", 1000.0, 0.01)
    v = np.asarray(good.velocity)
    v[len(v) // 2:] *= 1.05                                    # velocities 5 % off their accelerations' integral
    with pytest.raises(ValueError, match="its velocity changes by"):
        check_consistent(Reference(good.time_s, good.position, v, good.acceleration))
