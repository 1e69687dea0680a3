"""The panel's rclpy side (pkm_operator.panel_node): who counts as the reader of an
action. The recorder subscribes to every topic it discovers, the panel's among them;
a goal sent while only the recorder read ``goal`` was lost (a suite's hexapod panel
test: "done jog", the planner logged nothing, the yaw never moved)."""

import pytest
from geometry_msgs.msg import PoseStamped

from pkm_operator.panel import Panel, PanelModel
from pkm_operator.panel_node import PanelNode
from pkm_common.qos import STREAM_QOS
from pkm_kinematics import load_machine


@pytest.mark.ros
def test_only_the_planner_reading_goal_lets_a_jog_go_out(ros_graph):
    panel = Panel(PanelModel(load_machine("archi")))
    node = ros_graph.add_node(PanelNode(panel, "/pkm", context=ros_graph.context))
    recorder = ros_graph.create_node("recorder", namespace="/pkm")
    recorder.create_subscription(PoseStamped, "goal", lambda _: None, STREAM_QOS)
    assert ros_graph.spin_until(lambda: node.pubs["goal"].get_subscription_count() > 0, timeout_sec=10.0)
    assert node.receivers("goal", "trajectory") == 0
    assert "jog" in panel.snapshot()["unreached"]
    elsewhere = ros_graph.create_node("trajectory", namespace="/other")     # another graph's planner
    elsewhere.create_subscription(PoseStamped, "/pkm/goal", lambda _: None, STREAM_QOS)
    planner = ros_graph.create_node("trajectory", namespace="/pkm")
    planner.create_subscription(PoseStamped, "goal", lambda _: None, STREAM_QOS)
    assert ros_graph.spin_until(lambda: node.receivers("goal", "trajectory") == 1, timeout_sec=10.0)
    assert "jog" not in panel.snapshot()["unreached"]
