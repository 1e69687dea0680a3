"""Smoke test of the ROS 2 stack from PyPI wheels: two nodes, one process."""

import math
import os

import pytest

from pkm_common.domains import DDS_PROFILE

pytestmark = pytest.mark.ros

NAMES = ['q1', 'q2', 'q3', 'q4']
POSITIONS = [0.1, -1.5, math.pi, 1e-9]
VELOCITIES = [0.0, 2.5, -3.25, 1e300]
EFFORTS = [-100.0, 0.0, 12.5, float('inf')]


def test_session_has_private_domain():
    domain_id = int(os.environ['ROS_DOMAIN_ID'])
    assert domain_id != 0
    assert 1 <= domain_id <= 101 or 215 <= domain_id <= 232
    # on localhost over UDP only (pkm_common.domains.localhost_dds)
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    assert os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] == DDS_PROFILE


@pytest.mark.parametrize('ros_graph', ['single', 'events'], indirect=True)
def test_joint_state_round_trip(ros_graph):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    assert ros_graph.context.get_domain_id() == int(os.environ['ROS_DOMAIN_ID'])

    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    talker = ros_graph.create_node('smoke_talker', namespace='/pkm_test')
    listener = ros_graph.create_node('smoke_listener', namespace='/pkm_test')

    received = []
    listener.create_subscription(
        JointState, 'drives/state', received.append, qos)
    pub = talker.create_publisher(JointState, 'drives/state', qos)

    sent = []

    def publish():
        msg = JointState()
        msg.header.stamp = talker.get_clock().now().to_msg()
        msg.header.frame_id = 'world'
        msg.name = NAMES
        msg.position = POSITIONS
        msg.velocity = VELOCITIES
        msg.effort = EFFORTS
        pub.publish(msg)
        sent.append(msg)

    # Keep publishing until discovery has matched the two endpoints.
    talker.create_timer(0.05, publish)

    assert ros_graph.spin_until(lambda: received, timeout_sec=10.0), (
        f'no JointState received within 10 s ({len(sent)} sent)')

    msg = received[0]
    assert list(msg.name) == NAMES
    assert list(msg.position) == POSITIONS  # float64: bit-exact
    assert list(msg.velocity) == VELOCITIES
    assert list(msg.effort) == EFFORTS
    assert msg.header.frame_id == 'world'
    assert any(msg.header.stamp == s.header.stamp for s in sent)


@pytest.mark.parametrize('ros_graph', ['single', 'events'], indirect=True)
def test_background_spin_and_teardown(ros_graph):
    """Spinning in a thread; the fixture must stop it before destroying nodes."""
    from std_msgs.msg import String

    talker = ros_graph.create_node('bg_talker', namespace='/pkm_test')
    listener = ros_graph.create_node('bg_listener', namespace='/pkm_test')
    received = []
    listener.create_subscription(String, 'chatter', received.append, 10)
    pub = talker.create_publisher(String, 'chatter', 10)
    talker.create_timer(0.02, lambda: pub.publish(String(data='hello')))

    ros_graph.start()
    assert ros_graph.wait_until(lambda: len(received) >= 3, timeout_sec=10.0)
    assert received[0].data == 'hello'
    # Left spinning on purpose: the fixture's teardown stops the thread.
