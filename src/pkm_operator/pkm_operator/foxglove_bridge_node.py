"""``foxglove_bridge``: a running graph served live to Foxglove (pkm_operator.foxglove_live).

    .venv/bin/foxglove_bridge --ros-args -r __ns:=/pkm -p port:=8765 -p rate_hz:=30.0

in the graph's ROS_DOMAIN_ID (a ``pkm-run`` in realtime or lockstep mode). It only
subscribes; nothing it does reaches the machine.
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from visualization_msgs.msg import MarkerArray

from pkm_common import topics
from pkm_common.cdr import JointStateDecoder, ShownReader, decode_pose_stamped
from pkm_common.endpoints import subscription
from pkm_common.params import declare_float, declare_int
from pkm_common.runner import main_exit, run_node
from pkm_operator.foxglove_live import LiveChannels, joint_json, machine_scene, pose_in_frame


class FoxgloveBridgeNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("foxglove_bridge", context=context, **kwargs)
        port = declare_int(self, "port", 8765, 0, 65535, "the Foxglove WebSocket server's port (0: any free one)")
        rate_hz = declare_float(self, "rate_hz", 30.0, 0.1, 1000.0, "messages per stream per simulated second",
                                unit="Hz")
        self.live = LiveChannels(self.get_namespace(), port=port, rate_hz=rate_hz)
        self.port = self.live.server.port
        self.state_decoder = JointStateDecoder(topics.DRIVES_STATE)
        self._read = ShownReader(self.get_logger().error)       # a message it cannot read: dropped
        self.struts_decoder = JointStateDecoder(topics.METROLOGY_STRUTS)
        subscription(self, topics.DRIVES_STATE, self.on_state, raw=True)
        subscription(self, topics.METROLOGY_STRUTS, self.on_struts, raw=True)
        subscription(self, topics.TRUE_POSE, lambda b: self.on_pose(b, "tool/true_pose"), raw=True)
        subscription(self, topics.CONTROLLER_REFERENCE, lambda b: self.on_pose(b, "tool/reference"), raw=True)
        subscription(self, topics.MARKERS, self.on_markers)
        subscription(self, topics.CONTROLLER_STATUS, self.on_status)
        self.get_logger().info(f"Foxglove: ws://127.0.0.1:{self.port}")

    def on_state(self, buf: bytes) -> None:
        m = self._read(self.state_decoder.decode, buf)
        if m is not None:
            self.live.log("drives/state", joint_json(m.name, m.position, m.velocity, m.effort, m.frame_id),
                          m.stamp_ns)

    def on_struts(self, buf: bytes) -> None:
        m = self._read(self.struts_decoder.decode, buf)
        if m is not None:
            self.live.log("metrology/struts", joint_json(m.name, m.position, m.velocity, m.effort), m.stamp_ns)

    def on_pose(self, buf: bytes, stream: str) -> None:
        m = self._read(lambda b: decode_pose_stamped(b, stream), buf)
        if m is not None:
            self.live.log(stream, pose_in_frame(m.position, m.orientation, m.stamp_ns), m.stamp_ns)

    def on_markers(self, msg: MarkerArray) -> None:
        points = [(p.x, p.y, p.z) for marker in msg.markers for p in marker.points]
        if msg.markers:
            stamp = msg.markers[0].header.stamp
            self.live.log("machine", machine_scene(points, stamp.sec * 1_000_000_000 + stamp.nanosec),
                          stamp.sec * 1_000_000_000 + stamp.nanosec, decimate=False)

    def on_status(self, msg: DiagnosticArray) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for status in msg.status:          # level is a byte in rclpy's messages
            level = status.level[0] if isinstance(status.level, bytes) else int(status.level)
            self.live.log("controller/status", {"level": level, "message": status.message,
                                                "values": {kv.key: kv.value for kv in status.values}},
                          stamp, decimate=False)

    def destroy_node(self):
        if hasattr(self, "live"):
            self.live.close()
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(FoxgloveBridgeNode, args=args, name="foxglove_bridge"))


if __name__ == "__main__":
    main()
