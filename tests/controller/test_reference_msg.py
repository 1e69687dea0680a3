"""The trajectory message into the controller's Reference: read from its bytes (the
node's path) and from rclpy's message objects (the second reader) alike, bit for bit,
and equal to the samples it was made of (a planar yaw through +-pi unwrapped)."""

import math

import numpy as np
import pytest
from geometry_msgs.msg import Transform, Twist
from rclpy.serialization import deserialize_message, serialize_message
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

from pkm_common.cdr import decode_multidof_trajectory
from pkm_common.conversions import trajectory_msg
from pkm_controller.reference import reference_from_msg, reference_from_trajectory
from pkm_kinematics.task_space import PLANAR, POSITION, SPATIAL


def samples(planar: bool, n: int = 700):
    t = np.arange(n) * 0.004
    x = np.column_stack((1.0 + 0.01 * np.sin(t), -0.4 + 0.02 * t, (2.5 + 1.5 * t) if planar else 0.1 * t))
    v = np.column_stack((0.01 * np.cos(t), 0.02 + 0 * t, 1.5 + 0 * t if planar else 0.1 + 0 * t))
    a = np.column_stack((-0.01 * np.sin(t), 0 * t, 0 * t))
    return t, x, v, a


def message(planar: bool, t, x, v, a) -> MultiDOFJointTrajectory:
    msg = MultiDOFJointTrajectory(joint_names=["tool"])
    for tk, xk, vk, ak in zip(t, x, v, a):
        tf, vel, acc = Transform(), Twist(), Twist()
        tf.translation.x, tf.translation.y = float(xk[0]), float(xk[1])
        vel.linear.x, vel.linear.y, acc.linear.x, acc.linear.y = float(vk[0]), float(vk[1]), float(ak[0]), float(ak[1])
        if planar:
            tf.rotation.z, tf.rotation.w = math.sin(0.5 * xk[2]), math.cos(0.5 * xk[2])
            vel.angular.z, acc.angular.z = float(vk[2]), float(ak[2])
        else:
            tf.translation.z, vel.linear.z, acc.linear.z = float(xk[2]), float(vk[2]), float(ak[2])
            tf.rotation.w = 1.0
        point = MultiDOFJointTrajectoryPoint(transforms=[tf], velocities=[vel], accelerations=[acc])
        point.time_from_start.sec, point.time_from_start.nanosec = divmod(round(float(tk) * 1e9), 10**9)
        msg.points.append(point)
    return msg


@pytest.mark.parametrize("planar", [True, False])
def test_the_bytes_and_the_message_objects_give_the_same_reference(planar):
    t, x, v, a = samples(planar)
    buf = serialize_message(message(planar, t, x, v, a))
    space = PLANAR if planar else POSITION
    ref = reference_from_trajectory(decode_multidof_trajectory(buf), space)
    second = reference_from_msg(deserialize_message(buf, MultiDOFJointTrajectory), space)
    for field in ("time_s", "position", "velocity", "acceleration"):
        assert getattr(ref, field) == getattr(second, field), field          # bit for bit
    np.testing.assert_allclose(ref.time_s, t, rtol=0, atol=1e-12)
    # the planar yaw crosses pi (from 2.5 to 6.7 rad): continuous, as planned
    np.testing.assert_allclose(ref.position, x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ref.velocity, v, rtol=0, atol=0)
    np.testing.assert_allclose(ref.acceleration, a, rtol=0, atol=0)


def test_a_trajectory_of_another_shape_is_refused_by_name():
    msg = MultiDOFJointTrajectory(joint_names=["a", "b"])
    with pytest.raises(ValueError, match=r"expected one joint 'tool' and at least one point, got \['a', 'b'\]"):
        reference_from_trajectory(decode_multidof_trajectory(serialize_message(msg)), PLANAR)


def test_a_spatial_trajectory_reads_back_as_the_angles_and_rates_it_was_made_of():
    """A hexapod's samples written as trajectory_node writes them (conversions.trajectory_msg:
    quaternions and base-frame twists) read back as (x, y, z, a, b, c) with their rates
    and accelerations; the yaw c runs past pi and comes back unwrapped."""
    t = np.arange(400) * 0.005
    x = np.column_stack((0.01 * np.sin(t), 0.02 * t, 0.5 + 0 * t, 0.1 * np.sin(3 * t), -0.2 + 0.05 * t, 2.8 + 0.4 * t))
    v = np.column_stack((0.01 * np.cos(t), 0.02 + 0 * t, 0 * t, 0.3 * np.cos(3 * t), 0.05 + 0 * t, 0.4 + 0 * t))
    a = np.column_stack((-0.01 * np.sin(t), 0 * t, 0 * t, -0.9 * np.sin(3 * t), 0 * t, 0 * t))
    msg = trajectory_msg(SPATIAL, t, x, v, a)
    ref = reference_from_trajectory(decode_multidof_trajectory(serialize_message(msg)), SPATIAL)
    assert x[:, 5].max() > math.pi
    np.testing.assert_allclose(ref.position, x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ref.velocity, v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ref.acceleration, a, rtol=0, atol=1e-12)
    end, rest, _ = ref.sample(10.0)
    assert end == pytest.approx(x[-1].tolist(), abs=1e-12) and rest == [0.0] * 6
