"""``player_node``: republishes a recording (raw CDR, exactly as recorded).

Timing (``rate``): 1.0 replays with the original timing (recorded receive times),
2.0 twice as fast, 0 as fast as possible (a subscriber then needs a deep queue: the
graph's KEEP_LAST 10 would drop what its callbacks cannot keep up with). With ``step: true`` nothing is published
until the ``<ns>/player/step`` service (std_srvs/Trigger) is called: each call
publishes one simulated-time step — everything recorded up to and including the next
``/clock`` message — so a viewer or a controller under test can be
advanced cycle by cycle. Topics keep their recorded names (play into another
``ROS_DOMAIN_ID`` to keep a live graph apart); latched topics are republished
TRANSIENT_LOCAL. The node ends itself (exit 0) after the last message.
"""

from __future__ import annotations

import time
from pathlib import Path

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy
from std_srvs.srv import Trigger

from pkm_common.endpoints import message_class
from pkm_common.params import ParameterError, declare_bool, declare_float, declare_str
from pkm_common.qos import TOPIC_QOS, publisher_qos
from pkm_common.runner import main_exit, run_node

BATCH = 50           # messages per timer tick at most (as fast as possible)


class PlayerNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("player", context=context, **kwargs)
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
        bag = declare_str(self, "bag", "", "rosbag2 directory to play")
        self.rate = declare_float(self, "rate", 1.0, 0.0, 1000.0, "speed factor (0: as fast as possible)")
        self.step_mode = declare_bool(self, "step", False, "publish one /clock step per player/step call")
        topics = declare_str(self, "topics", "", "comma-separated topics (empty: all)", allow_empty=True)
        if not (Path(bag) / "metadata.yaml").is_file():
            raise ParameterError("bag", f"must be a rosbag2 directory with metadata.yaml, got {bag!r}")
        wanted = {t.strip() for t in topics.split(",") if t.strip()}
        self.reader = AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        self.reader.open()
        connections = [c for c in self.reader.connections if not wanted or c.topic in wanted]
        self.publishers_by_id = {}
        for c in connections:
            relative = c.topic.split("/", 2)[-1] if c.topic.count("/") > 1 else c.topic
            qos = publisher_qos(relative if relative in TOPIC_QOS else c.topic)
            self.publishers_by_id[c.id] = self.create_publisher(message_class(c.msgtype), c.topic, qos)
        self.clock_ids = {c.id for c in connections if c.topic == "/clock"}
        self.messages = self.reader.messages(connections=connections)
        self.pending = next(self.messages, None)
        self.published = 0
        self.t0_bag = self.pending[1] if self.pending else 0
        self.t0_wall = None
        self.created_s = time.monotonic()
        self.shutdown_on_end = declare_bool(self, "shutdown_on_end", True, "end the process after the last message")
        if self.step_mode:
            self.create_service(Trigger, "player/step", self.on_step)
        else:
            self.create_timer(0.001, self.on_tick)

    def _publish(self, item) -> None:
        connection, _, raw = item
        self.publishers_by_id[connection.id].publish(raw)
        self.published += 1

    def _advance(self):
        self.pending = next(self.messages, None)
        if self.pending is None:                  # called only while messages were pending
            self.get_logger().info(f"played {self.published} messages")

    def on_tick(self) -> None:
        if self.t0_wall is None:
            if any(p.get_subscription_count() == 0 for p in self.publishers_by_id.values()
                   if p.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL) \
                    and time.monotonic() - self.created_s < 2.0:
                return                     # give subscribers up to 2 s to match
            self.t0_wall = time.monotonic_ns()
        for _ in range(BATCH):
            if self.pending is None:
                break
            if self.rate > 0:
                due = self.t0_wall + (self.pending[1] - self.t0_bag) / self.rate
                if time.monotonic_ns() < due:
                    break
            self._publish(self.pending)
            self._advance()
        if self.pending is None:
            self.finish()

    def on_step(self, request, response):
        """One simulated-time step: everything recorded up to and including the next
        /clock message (sim_hw publishes a step's pose and state, then its clock)."""
        count = 0
        while self.pending is not None:
            is_clock = self.pending[0].id in self.clock_ids
            self._publish(self.pending)
            self._advance()
            count += 1
            if is_clock:
                break
        response.success = count > 0
        response.message = f"published {count} messages" if count else "end of recording"
        return response

    def finish(self) -> None:
        if self.shutdown_on_end:
            rclpy.try_shutdown(context=self.context)

    def destroy_node(self):
        if getattr(self, "reader", None) is not None:
            self.reader.close()
            self.reader = None
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(PlayerNode, args=args, name="player", executor="events"))


if __name__ == "__main__":
    main()
