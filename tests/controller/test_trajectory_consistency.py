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


def limits_of(space) -> Limits:
    """trajectory_node's default limits (per translation and angle axis)."""
    dof, ta = space.dof, space.translation_axes
    return Limits(tuple([0.5] * ta + [2.0] * (dof - ta)), tuple([5.0] * ta + [20.0] * (dof - ta)),
                  tuple([200.0] * ta + [800.0] * (dof - ta)))


def read_back(model, samples) -> Reference:
    """``samples`` as the controller node reads them: a message, its bytes, the Reference."""
    msg = trajectory_msg(model.task_space, samples.time_s, samples.position, samples.velocity, samples.acceleration)
    return reference_from_trajectory(decode_multidof_trajectory(serialize_message(msg)), model.task_space)


def planned(machine: str, rate_hz: float, far) -> Reference:
    """A move from home by ``far`` (per task axis), planned and read back as the node does."""
    model = load_machine(machine).model
    home = np.asarray(model.home, dtype=float)
    samples = plan([Line(tuple(home), tuple(home + np.asarray(far)))], limits_of(model.task_space), rate_hz,
                   translation_axes=model.task_space.translation_axes)
    return read_back(model, samples)


# a move on every axis, and a turn alone: the jerk of an angle (800 rad/s^3) changes
# sign within a 4 ms step, where the trapezoid of the accelerations is off by 1.6e-3
# rad/s (a fixed 1e-3 tolerance refused ARCHI's 0.5 rad jog at 250 Hz)
@pytest.mark.parametrize("machine, far", [("archi", 0.02), ("archi", [0.0, 0.0, 0.5]), ("orthoglide", 0.02),
                                          ("hexapod8", 0.02), ("hexapod8", [0.01, 0.0, 0.0, 0.1, 0.1, 0.2])])
@pytest.mark.parametrize("rate_hz", [100.0, 250.0, 1000.0])
def test_what_the_planner_makes_passes(machine, far, rate_hz):
    check_consistent(planned(machine, rate_hz, far))


@pytest.mark.parametrize("program, machine", [("archi_test_motion.nc", "archi"), ("orthoglide_cube.nc", "orthoglide"),
                                              ("mom3_square.nc", "mom3"), ("hexapod_metrology.nc", "hexapod8"),
                                              ("sliding_star_loops.nc", "sliding_star")])
def test_the_shipped_programs_pass_at_250_hz(program, machine):
    from pathlib import Path

    from pkm_trajectory.planner import plan_validated
    from pkm_trajectory.program import gcode_segments
    model = load_machine(machine).model
    text = (Path(__file__).resolve().parents[2] / "config" / "programs" / program).read_text()
    segments = gcode_segments(text, model.task_space, start_pose=[float(v) for v in model.home])
    samples = plan_validated(segments, model, limits_of(model.task_space), 250.0, 0.0, 2.0, 50.0, 50.0)
    check_consistent(read_back(model, samples))


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
