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


@pytest.mark.ros
def test_endpoints_take_type_and_qos_from_the_catalogue(ros_graph):
    """pkm_common.endpoints: a publisher offers publisher_qos (the streams' deeper
    history), a subscription asks for TOPIC_QOS, both of the catalogue's type; a name
    outside the catalogue is refused by name."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Bool

    from pkm_common.endpoints import publisher, subscription
    from pkm_common.qos import EVENTS_QOS, STREAM_PUBLISHER_QOS
    node = ros_graph.create_node('endpoints_test', namespace='/pkm_endpoints_test')
    state = publisher(node, 'drives/state')
    assert state.msg_type is JointState and state.qos_profile.depth == STREAM_PUBLISHER_QOS.depth == 500
    estop = subscription(node, 'estop', lambda m: None)
    assert estop.msg_type is Bool and estop.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert publisher(node, 'controller/events').qos_profile.depth == EVENTS_QOS.depth
    with pytest.raises(KeyError, match="'drives/other' is not in pkm_common.topics.CATALOGUE"):
        publisher(node, 'drives/other')


def test_nodes_open_the_graphs_topics_through_the_catalogue():
    """No node names a topic of the graph in a create_publisher / create_subscription
    of its own: they go through pkm_common.endpoints (the recorder, the player and the
    tap, which wire topics they discover, read from a bag or keep private, excepted)."""
    from pathlib import Path
    src = Path(__file__).resolve().parents[2] / "src"
    generic = {"endpoints.py", "recorder_node.py", "player_node.py", "node_tap.py"}
    offenders = [f"{path.relative_to(src)}:{n}" for path in sorted(src.rglob("*.py")) if path.name not in generic
                 for n, line in enumerate(path.read_text().splitlines(), 1)
                 if "create_publisher(" in line or "create_subscription(" in line]
    assert not offenders, offenders
