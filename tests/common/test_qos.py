"""pkm_common.qos: the profiles of DESIGN.md's topics, and that endpoints using them match."""

import pytest
from rclpy.qos import DurabilityPolicy, HistoryPolicy, ReliabilityPolicy

from pkm_common.qos import CLOCK_QOS, LATCHED_QOS, STREAM_QOS, TOPIC_QOS


def test_profiles():
    assert (STREAM_QOS.reliability, STREAM_QOS.history, STREAM_QOS.depth, STREAM_QOS.durability) == (
        ReliabilityPolicy.RELIABLE, HistoryPolicy.KEEP_LAST, 10, DurabilityPolicy.VOLATILE)
    assert (LATCHED_QOS.reliability, LATCHED_QOS.history, LATCHED_QOS.depth, LATCHED_QOS.durability) == (
        ReliabilityPolicy.RELIABLE, HistoryPolicy.KEEP_LAST, 1, DurabilityPolicy.TRANSIENT_LOCAL)
    assert (CLOCK_QOS.reliability, CLOCK_QOS.depth) == (ReliabilityPolicy.BEST_EFFORT, 1)
    for topic in ('drives/state', 'drives/command', 'platform/true_pose', 'metrology/struts',
                  'metrology/pose', 'controller/reference', 'controller/status'):
        assert TOPIC_QOS[topic] is STREAM_QOS
    assert TOPIC_QOS['trajectory'] is LATCHED_QOS and TOPIC_QOS['markers'] is LATCHED_QOS


@pytest.mark.ros
def test_latched_message_reaches_a_late_subscriber(ros_graph):
    from std_msgs.msg import String
    talker = ros_graph.create_node('qos_talker', namespace='/pkm_qos_test')
    pub = talker.create_publisher(String, 'trajectory', LATCHED_QOS)
    pub.publish(String(data='plan'))
    listener = ros_graph.create_node('qos_listener', namespace='/pkm_qos_test')
    got = []
    listener.create_subscription(String, 'trajectory', got.append, LATCHED_QOS)
    assert ros_graph.spin_until(lambda: got, timeout_sec=10.0)
    assert got[0].data == 'plan'


def test_the_topic_catalogue_names_real_message_types_and_profiles():
    """pkm_common.topics: every type imports (rosidl), every topic has its profile."""
    import importlib

    from pkm_common.topics import CATALOGUE, QOS_KINDS
    assert {"drives/state", "trajectory", "controller/events", "estop", "/clock"} <= set(CATALOGUE)
    for name, topic in CATALOGUE.items():
        package, _, kind = topic.type.split("/")
        assert hasattr(importlib.import_module(f"{package}.msg"), kind), topic
        assert topic.qos in QOS_KINDS and name in TOPIC_QOS, topic
    assert TOPIC_QOS["controller/events"] is not STREAM_QOS and TOPIC_QOS["run/start"] is LATCHED_QOS
