"""pkm_common.conversions: stamps, poses, joint states, machine poses, diagnostics.

Rotations are checked against scipy's Rotation (an independent quaternion code).
"""

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from scipy.spatial.transform import Rotation

from pkm_kinematics.task_space import PLANAR, POSITION, SPATIAL
from pkm_common.conversions import (diagnostic_array, diagnostic_status, joint_state_msg, line_list_markers,
                                    ns_to_stamp, pose_from_msg, pose_msg, stamp_to_ns)
from pkm_common.poses import machine_pose_components, machine_to_tool_pose, tool_pose_to_machine


# ------------------------------------------------------------------- stamps
@pytest.mark.parametrize('ns', [0, 1, 999_999_999, 1_000_000_000, 1_234_567_890_123_456_789 // 1000,
                                (2**31 - 1) * 10**9 + 999_999_999])
def test_stamps_round_trip_exactly(ns):
    stamp = ns_to_stamp(ns)
    assert 0 <= stamp.nanosec < 10**9
    assert stamp.sec == ns // 10**9
    assert stamp_to_ns(stamp) == ns


@pytest.mark.parametrize('bad', [-1, 2**31 * 10**9, 1.5, True, '5'])
def test_bad_stamps_are_refused(bad):
    with pytest.raises(ValueError, match='stamp'):
        ns_to_stamp(bad)


def test_stamp_from_rclpy_time():
    from rclpy.time import Time as RclpyTime
    msg = pose_msg([0.0, 0.0, 0.0], np.eye(3), RclpyTime(nanoseconds=5_000_000_123), 'world')
    assert stamp_to_ns(msg.header.stamp) == 5_000_000_123


# -------------------------------------------------------------------- poses
def test_pose_round_trip_against_scipy():
    rng = np.random.default_rng(0)
    for rot in Rotation.random(200, random_state=1):
        p = rng.uniform(-2, 2, 3)
        msg = pose_msg(p, rot.as_matrix(), 123, 'world')
        assert msg.header.frame_id == 'world' and stamp_to_ns(msg.header.stamp) == 123
        q = msg.pose.orientation
        assert q.w >= 0.0
        # the message quaternion is scipy's (x, y, z, w), up to the sign
        ref = rot.as_quat()
        assert min(np.abs([q.x, q.y, q.z, q.w] - ref).max(), np.abs([q.x, q.y, q.z, q.w] + ref).max()) < 1e-12
        p2, r2 = pose_from_msg(msg)
        np.testing.assert_array_equal(p2, p)
        np.testing.assert_allclose(r2, rot.as_matrix(), atol=1e-14)


def _msg(position=(0.1, 0.2, 0.3), quat=(0.0, 0.0, 0.0, 1.0)):
    msg = PoseStamped()
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = position
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = quat
    return msg


@pytest.mark.parametrize('position,quat,field', [
    ((0.0, math.nan, 0.0), (0, 0, 0, 1.0), 'pose.position.y'),
    ((math.inf, 0.0, 0.0), (0, 0, 0, 1.0), 'pose.position.x'),
    ((0.0, 0.0, 0.0), (0, 0, 0, math.nan), 'pose.orientation.w'),
    ((0.0, 0.0, 0.0), (0, 0, 0, 0.0), 'pose.orientation: must be a unit quaternion'),
    ((0.0, 0.0, 0.0), (0, 0, 0, 1.1), r'\|q\| = 1.1'),
    ((0.0, 0.0, 0.0), (0, 0, 0, 1.0 + 2e-6), 'pose.orientation'),
])
def test_bad_poses_name_the_field(position, quat, field):
    with pytest.raises(ValueError, match=field):
        pose_from_msg(_msg(position, quat))


def test_nearly_unit_quaternion_is_normalised():
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q = q / np.linalg.norm(q) * (1.0 + 5e-7)
    _, rot = pose_from_msg(_msg(quat=tuple(q)))
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(rot, Rotation.from_quat(q).as_matrix(), atol=1e-15)


def test_pose_msg_refuses_nan_and_bad_shapes():
    with pytest.raises(ValueError, match='NaN'):
        pose_msg([0.0, math.nan, 0.0], np.eye(3), 0, 'world')
    with pytest.raises(ValueError, match='NaN'):
        pose_msg([0.0, 0.0, 0.0], np.full((3, 3), np.nan), 0, 'world')
    with pytest.raises(ValueError, match='position'):
        pose_msg([0.0, 0.0], np.eye(3), 0, 'world')
    with pytest.raises(ValueError, match='rotation'):
        pose_msg([0.0, 0.0, 0.0], np.eye(4), 0, 'world')


# ------------------------------------------------------------- joint states
def test_joint_state_msg():
    msg = joint_state_msg(['q1', 'q2'], Time(sec=3, nanosec=4), position=np.array([0.1, 0.2]),
                          effort=[5, -6.5])
    assert list(msg.name) == ['q1', 'q2']
    assert list(msg.position) == [0.1, 0.2]
    assert list(msg.velocity) == []
    assert list(msg.effort) == [5.0, -6.5]
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 4)
    with pytest.raises(ValueError, match='velocity: expected 2 values'):
        joint_state_msg(['q1', 'q2'], 0, velocity=[1.0])


# ------------------------------------------------------- machine <-> tool pose
def test_planar_machine_pose_to_tool_pose_and_back():
    p, rot = machine_to_tool_pose(PLANAR, [0.5, -0.25, 2.0])
    np.testing.assert_array_equal(p, [0.5, -0.25, 0.0])
    np.testing.assert_allclose(rot, Rotation.from_euler('z', 2.0).as_matrix(), atol=1e-15)
    x = tool_pose_to_machine(PLANAR, p, rot)
    np.testing.assert_allclose(x, [0.5, -0.25, 2.0], atol=1e-15)


@pytest.mark.parametrize('theta,reference', [(7.0, 6.5), (-9.0, -9.5), (100.0, 99.0), (3.1, -3.1)])
def test_planar_yaw_is_unwrapped_to_the_reference_revolution(theta, reference):
    p, rot = machine_to_tool_pose(PLANAR, [0.0, 0.0, theta])
    x = tool_pose_to_machine(PLANAR, p, rot, reference_theta=reference)
    assert abs(x[2] - reference) <= math.pi
    assert math.isclose(math.remainder(x[2] - theta, 2 * math.pi), 0.0, abs_tol=1e-12)
    without = tool_pose_to_machine(PLANAR, p, rot)[2]
    assert -math.pi <= without <= math.pi


def test_translational_machine_pose():
    p, rot = machine_to_tool_pose(POSITION, [0.1, 0.2, 0.9])
    np.testing.assert_array_equal(p, [0.1, 0.2, 0.9])
    np.testing.assert_array_equal(rot, np.eye(3))
    np.testing.assert_array_equal(tool_pose_to_machine(POSITION, p, rot), p)


@pytest.mark.parametrize('space, x', [(PLANAR, (0.1, -0.6, 0.25 * math.pi)), (PLANAR, (0.0, 0.2, -2.5)),
                                      (POSITION, (0.01, -0.02, 0.03)), (SPATIAL, (0.01, -0.02, 0.5, 0.1, 0.2, -0.3))])
def test_machine_pose_components_are_the_tool_pose_as_message_fields(space, x):
    position, orientation = machine_pose_components(space, x)
    p, r = machine_to_tool_pose(space, x)
    assert tuple(position) == tuple(p)
    assert np.allclose(Rotation.from_quat(orientation).as_matrix(), r, atol=1e-12)
    assert all(type(v) is float for v in (*position, *orientation))


def test_machine_pose_errors():
    with pytest.raises(ValueError, match='space: must be a task space'):
        machine_to_tool_pose('planar', [0, 0, 0])
    with pytest.raises(ValueError, match=r'x: expected 3 finite numbers \(x, y, theta\)'):
        machine_to_tool_pose(PLANAR, [0, 0])
    with pytest.raises(ValueError, match='x: expected 3 finite'):
        machine_to_tool_pose(POSITION, [0, math.nan, 0])
    with pytest.raises(ValueError, match=r'x: expected 6 finite numbers \(x, y, z, a, b, c\)'):
        machine_to_tool_pose(SPATIAL, [0, 0, 0])
    with pytest.raises(ValueError, match='reference_theta'):
        tool_pose_to_machine(PLANAR, [0, 0, 0], np.eye(3), reference_theta=math.inf)


# -------------------------------------------------------------- diagnostics
def test_diagnostic_status_and_array():
    value = 0.1 + 0.2
    status = diagnostic_status('gough_sensor: metrology', 2, 'DKM failed',
                               {'residual_m': value, 'iterations': 12, 'count': np.int64(3),
                                'reason': 'diverged'}, hardware_id='gough')
    assert status.level == DiagnosticStatus.ERROR
    values = {kv.key: kv.value for kv in status.values}
    assert float(values['residual_m']) == value            # repr: exact round trip
    assert values == {'residual_m': repr(value), 'iterations': '12', 'count': '3', 'reason': 'diverged'}
    assert status.hardware_id == 'gough'
    assert diagnostic_status('x', DiagnosticStatus.WARN, 'w', {}).level == DiagnosticStatus.WARN
    array = diagnostic_array(2_500_000_000, [status])
    assert (array.header.stamp.sec, array.header.stamp.nanosec) == (2, 500_000_000)
    assert array.status[0].name == 'gough_sensor: metrology'
    with pytest.raises(ValueError, match='level'):
        diagnostic_status('x', 7, 'bad')


def test_line_list_markers_hold_each_segment_as_a_pair_of_points():
    markers = line_list_markers([([0.0, 1.0, 2.0], [3.0, 4.0, 5.0]), ([6.0, 7.0, 8.0], [9.0, 10.0, 11.0])],
                                1_500_000_000)
    (marker,) = markers.markers
    assert marker.type == marker.LINE_LIST and marker.header.frame_id == "world"
    assert (marker.header.stamp.sec, marker.header.stamp.nanosec) == (1, 500_000_000)
    assert [(p.x, p.y, p.z) for p in marker.points] == [(0.0, 1.0, 2.0), (3.0, 4.0, 5.0), (6.0, 7.0, 8.0),
                                                        (9.0, 10.0, 11.0)]


def test_a_spatial_pose_is_published_with_its_roll_pitch_yaw_rotation():
    from scipy.spatial.transform import Rotation

    from pkm_common.poses import machine_pose_components, machine_to_tool_pose, tool_pose_to_machine
    x = [0.1, -0.2, 0.5, 0.3, -0.2, 1.1]
    position, quaternion = machine_pose_components(SPATIAL, x)
    expected = Rotation.from_euler("ZYX", [1.1, -0.2, 0.3]).as_quat()      # R = Rz(c) Ry(b) Rx(a)
    assert position == (0.1, -0.2, 0.5)
    np.testing.assert_allclose(np.abs(np.dot(quaternion, expected)), 1.0, atol=1e-15)
    p, r = machine_to_tool_pose(SPATIAL, x)
    np.testing.assert_allclose(tool_pose_to_machine(SPATIAL, p, r), x, atol=1e-15)
    np.testing.assert_allclose(tool_pose_to_machine(SPATIAL, p, r, reference_theta=9.0), x, atol=1e-15)
