"""The operator panel's rclpy side (thin shell over panel.Panel): subscribes to what the
panel shows, publishes what its actions ask for, and runs the jog watchdog on the
executor's own thread, so that a stuck web loop still holds a jog whose page went
silent. Nothing here reaches the drives: the panel talks to the controller and the
planner only (``estop``, ``program``, ``goal``, ``controller/feed_override``,
``controller/settings``), and the controller decides. With the run's key (``key``)
every command but the E-stop carries the run's credential (pkm_common.credential).
"""

from __future__ import annotations

import math
import threading

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from std_msgs.msg import Bool, String

from pkm_common import topics
from pkm_common.cdr import JointStateDecoder, ShownReader, decode_pose_stamped
from pkm_common.conversions import signed_message
from pkm_common.credential import Signer
from pkm_common.endpoints import publisher, subscription
from pkm_common.poses import machine_pose_components

WATCHDOG_PERIOD_S = 0.05


class PanelNode(Node):
    def __init__(self, panel, namespace: str = "/pkm", context=None, key=None):
        super().__init__("panel", namespace=namespace, context=context)
        self.panel = panel
        # the run's credential (None: the commands go without one); a reset's new run
        # sets ``signer.key``
        self.signer = Signer(key, self.get_fully_qualified_name()) if key is not None else None
        self.publish_lock = threading.Lock()
        self.state_decoder = JointStateDecoder(topics.DRIVES_STATE)
        self._read = ShownReader(self.get_logger().error)       # a message it cannot read: dropped
        # the commands it sends, by topic
        self.pubs = {topic: publisher(self, topic) for topic in (topics.ESTOP, topics.PROGRAM, topics.GOAL,
                                                                 topics.FEED_OVERRIDE, topics.SETTINGS)}
        subscription(self, topics.DRIVES_STATE, self.on_state, raw=True)
        subscription(self, topics.TRUE_POSE, self.on_true_pose, raw=True)
        subscription(self, topics.METROLOGY_STRUTS, lambda _: panel.on_struts(), raw=True)
        subscription(self, topics.CONTROLLER_REFERENCE, self.on_reference, raw=True)
        subscription(self, topics.CONTROLLER_STATUS, self.on_status)
        subscription(self, topics.DIAGNOSTICS, self.on_status)
        subscription(self, topics.DRIVES_CIA402, self.on_drive_states)
        subscription(self, topics.ESTOP, lambda m: panel.on_estop(bool(m.data)))
        subscription(self, topics.CONTROLLER_EVENTS, lambda m: panel.on_event(m.data))
        self.create_timer(WATCHDOG_PERIOD_S, self.on_watchdog)
        panel.connect(self.receivers)

    def receivers(self, topic: str, node: str) -> int:
        """Subscriptions of ``node`` (in the panel's namespace) on ``topic``, once the
        panel's publisher has matched every reader the graph knows: any other reader,
        such as the recorder, which subscribes to every topic it discovers, is not the
        one an action is for (a goal went to the recorder alone and was lost), and a
        node is known by name before its reader is matched."""
        readers = self.get_subscriptions_info_by_topic(topic)
        if self.pubs[topic].get_subscription_count() < len(readers):
            return 0
        return sum(info.node_name == node and info.node_namespace == self.get_namespace() for info in readers)

    def on_state(self, buf: bytes) -> None:
        m = self._read(self.state_decoder.decode, buf)
        if m is not None:
            self.panel.on_state(m.stamp_ns, m.name, m.position, m.velocity, m.effort, m.frame_id)

    def on_true_pose(self, buf: bytes) -> None:
        m = self._read(lambda b: decode_pose_stamped(b, "platform/true_pose"), buf)
        if m is not None:
            self.panel.on_true_pose(m.stamp_ns, m.position, m.orientation)

    def on_reference(self, buf: bytes) -> None:
        m = self._read(lambda b: decode_pose_stamped(b, "controller/reference"), buf)
        if m is not None:
            self.panel.on_reference(m.stamp_ns, m.position, m.orientation)

    def on_status(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.panel.on_status(*_status_fields(status))

    def on_drive_states(self, msg: DiagnosticArray) -> None:
        self.panel.on_drive_states([_status_fields(status) for status in msg.status])

    def on_watchdog(self) -> None:
        result = self.panel.watchdog()
        if result is not None:
            self.publish(result.publish)
            self.get_logger().warning(result.message)

    def publish(self, items) -> None:
        """[(topic, payload)] of a panel.Result (thread-safe: rcl publishers are). A
        command is signed and published under one lock (its seq in order,
        credential.py); the E-stop, unsigned, does not wait for it."""
        for topic, payload in items:
            if topic == "estop":
                self.pubs[topic].publish(Bool(data=bool(payload)))
            else:
                with self.publish_lock:
                    self._publish(topic, payload)

    def _publish(self, topic: str, payload) -> None:
        """One command, with the run's credential when the panel holds the key."""
        if topic == "goal":
            msg = PoseStamped()
            msg.header.frame_id = "world"
            position, orientation = machine_pose_components(self.panel.model.space, payload)
            p, o = msg.pose.position, msg.pose.orientation
            p.x, p.y, p.z = (float(v) for v in position)
            o.x, o.y, o.z, o.w = (float(v) for v in orientation)
            self.pubs[topic].publish(signed_message(self.signer, topic, msg))
        else:                             # a String: the program, the settings, the feed override
            body = repr(float(payload)) if topic == "controller/feed_override" else payload
            self.pubs[topic].publish(self.signer.text(topic, body) if self.signer else String(data=body))


def _status_fields(status) -> tuple:
    """(name, level, message, values) of a DiagnosticStatus: its level a byte in rclpy's
    messages, numbers as numbers ("nan"/"inf" stay text: not JSON)."""
    level = status.level[0] if isinstance(status.level, bytes) else int(status.level)
    values = {}
    for kv in status.values:
        try:
            number = float(kv.value)
        except ValueError:
            number = math.nan
        values[kv.key] = number if math.isfinite(number) else kv.value
    return status.name, level, status.message, values
