"""``recorder_node``: records the graph to a rosbag2-compatible MCAP directory.

Thin shell over :class:`pkm_recording.bag.BagWriter`. Every topic (but
``/parameter_events``, or the ``topics`` listed) is subscribed **raw** and written as
published (re-serialising adds bytes rosbags refuses), discovered every
``discovery_period_s`` until ready, then every ``running_discovery_period_s``, with
the QoS its publishers offer, recorded in the channel metadata. Counts: messages per
topic and those with a new stamp (CDR bytes 4-12), as the nodes count theirs.

Tapped topics (``tapped_topics``): the loop's per-step streams, whose nodes run with
``tap: true`` (pkm_recording.tap), are not subscribed: their nodes send batches on
``_recorder/tap`` (one per node every 0.2 s, off the loop's critical path), written a
batch in one compiled pass (pkm_recording.tap_records) with the publish times as log
times. Refused whole: a malformed batch (``tap_errors``), and one received while a
node not in ``tap_sources`` publishes on the tap (``tap_forged``: it would be recorded
as the graph's own data). In one process the taps call ``write_records`` directly.

Readiness: once every topic of ``expect_topics`` is subscribed and matched, the node
logs ``recorder ready`` and touches ``ready_file`` (the orchestrator starts then).

Chunks are lz4 by default (``compression``: ~4x faster than zstd for 2.5x instead of
3.3x smaller). The bag is flushed every ``flush_period_s`` (a kill -9 loses at most
the open chunk, bag.recover) and finalized when the node is destroyed (runner.run_node).
"""

from __future__ import annotations

import time
from pathlib import Path

from rclpy.node import Node
from std_msgs.msg import UInt8MultiArray

from pkm_common.cdr import stamp_ns_of
from pkm_common.conversions import graph_senders
from pkm_common.endpoints import message_class
from pkm_common.files import reserve_file, write_summary
from pkm_common.params import declare_float, declare_int, declare_str
from pkm_common.qos import TAP_QOS
from pkm_common.runner import main_exit, run_node
from pkm_common.sources import AllowedSenders, node_names
from pkm_recording.bag import BagWriter
from pkm_recording.recording import lower_cpu_priority, qos_dict, subscription_qos
from pkm_recording.tap import TAP_TOPIC, split_batch
from pkm_recording.tap_records import StampCounter

EXCLUDED = ("/parameter_events",)
TAPPED = "tapped"           # subscriptions_by_topic: recorded through the tap, not subscribed


# recorded whatever the run's namespace (the loop's clock, every node's log)
GLOBAL_TOPICS = ("/clock", "/rosout")


class RecorderNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("recorder", context=context, **kwargs)
        self.writer = None
        output = declare_str(self, "output", "", "rosbag2 directory to create (must not exist)")
        topics = declare_str(self, "topics", "", "comma-separated topic names; empty: every topic",
                             allow_empty=True)
        expect = declare_str(self, "expect_topics", "", "comma-separated topics that must be subscribed "
                             "and matched before the node is ready", allow_empty=True)
        tapped = declare_str(self, "tapped_topics", "", "comma-separated topics whose publishers send them "
                             "through the recording tap (pkm_recording.tap) instead", allow_empty=True)
        self.tap_senders = AllowedSenders(TAP_TOPIC, node_names(declare_str(
            self, "tap_sources", "", "full node names allowed to publish tap batches (empty: any)",
            allow_empty=True)), "tap_sources")
        self.tap_forged = 0                  # batches refused: a node not named published on the tap
        self.ready_file = declare_str(self, "ready_file", "", "touched when ready", allow_empty=True)
        self.summary_path = declare_str(self, "summary_path", "", "JSON counts at exit", allow_empty=True)
        if self.summary_path:
            reserve_file(self.summary_path)
        self.depth = declare_int(self, "depth", 1000, 1, 100000, "subscription queue depth")
        flush = declare_float(self, "flush_period_s", 0.5, 0.01, 60.0, "bag flush period", unit="s")
        discovery = declare_float(self, "discovery_period_s", 0.1, 0.01, 10.0, "until ready", unit="s")
        self.running_discovery = declare_float(self, "running_discovery_period_s", 1.0, 0.01, 60.0,
                                               "once ready: a topic that appears later is recorded "
                                               "from at most this long after its first message", unit="s")
        priority = declare_str(self, "cpu_priority", "normal", "idle: the whole process (DDS threads "
                               "included) runs only on CPU time the loop leaves (SCHED_IDLE); only for a "
                               "recorder in its own process", choices=("normal", "idle"))
        compression = declare_str(self, "compression", "lz4", "chunk compression: lz4 (~4x faster than "
                                  "zstd, files ~1.25x larger), zstd or none", choices=("lz4", "zstd", "none"))
        if priority == "idle":
            self.get_logger().info(f"SCHED_IDLE for {lower_cpu_priority()} threads")
        self.topics = {self.resolve(t) for t in topics.split(",") if t.strip()}
        self.expect = {self.resolve(t) for t in expect.split(",") if t.strip()}
        self.tapped = {self.resolve(t) for t in tapped.split(",") if t.strip()}
        self.tap_topic = self.resolve(TAP_TOPIC)
        self.writer = BagWriter(output, compression=compression)
        self.subscriptions_by_topic = {}     # topic -> subscription, TAPPED, or None (not recordable)
        self.channels = {}                   # topic -> channel id
        # per channel id, the messages with a new stamp (repeats of a stamp not counted),
        # subscribed or tapped
        self.stamps = StampCounter()
        self.tap_errors = 0
        self.tap_batches = 0                 # tap batches received as messages
        self.tap_lists = 0                   # ... payloads handed over in the same process (NodeTap.sink)
        self.tap_refused = set()             # (topic, type) of tap batches that cannot be recorded
        if self.tapped:
            self.tap_subscription = self.create_subscription(
                UInt8MultiArray, self.tap_topic, self.on_tap, subscription_qos([TAP_QOS], self.depth), raw=True)
        self.ready = False
        self.discovery_timer = self.create_timer(discovery, self.discover)
        self.create_timer(flush, self.writer.flush)
        self.discover()

    def resolve(self, topic: str) -> str:
        topic = topic.strip()
        return topic if topic.startswith("/") else f"{self.get_namespace().rstrip('/')}/{topic}"

    @property
    def steps(self) -> dict[str, int]:
        """Per topic recorded, the messages with a new header stamp."""
        return {name: self.stamps.count(channel) for name, channel in self.channels.items()}

    def _add_channel(self, name: str, msgtype: str, infos) -> int | None:
        try:
            message_class(msgtype)
            channel = self.writer.add_topic(name, msgtype, [qos_dict(i.qos_profile) for i in infos])
        except (ImportError, AttributeError, TypeError, ValueError) as exc:
            self.get_logger().warning(f"{name}: not recorded ({exc})")
            return None
        self.channels[name] = channel
        self.stamps.reserve(channel)
        return channel

    def in_scope(self, name: str) -> bool:
        """The topics of this run: its namespace's, and the global /clock and /rosout
        (another run beside it in another namespace of the domain is not recorded)."""
        prefix = self.get_namespace().rstrip("/") + "/"
        return name.startswith(prefix) or name in GLOBAL_TOPICS

    def discover(self) -> None:
        for name, types in self.get_topic_names_and_types():
            if name in self.subscriptions_by_topic or name in EXCLUDED or name == self.tap_topic \
                    or (self.topics and name not in self.topics) or not self.in_scope(name):
                continue
            infos = self.get_publishers_info_by_topic(name)
            if not infos or len(types) != 1:
                continue
            channel = self._add_channel(name, types[0], infos)
            if channel is None or name in self.tapped:
                self.subscriptions_by_topic[name] = None if channel is None else TAPPED
                continue
            write, count = self.writer.write, self.stamps.add_one

            def callback(data: bytes, channel=channel):
                write(channel, time.time_ns(), data)
                count(channel, stamp_ns_of(data) if len(data) >= 12 else -1)

            self.subscriptions_by_topic[name] = self.create_subscription(
                message_class(types[0]), name, callback,
                subscription_qos([i.qos_profile for i in infos], self.depth), raw=True)
        if not self.ready and all(self._receiving(t) for t in self.expect):
            self.ready = True
            self.discovery_timer.timer_period_ns = round(self.running_discovery * 1e9)
            self.get_logger().info(f"recorder ready: {len(self.subscriptions_by_topic)} topics")
            if self.ready_file:
                Path(self.ready_file).touch()

    def _receiving(self, topic: str) -> bool:
        """Subscribed and matched; for a tapped topic, every node publishing it also
        publishes on the tap."""
        sub = self.subscriptions_by_topic.get(topic)
        if sub is None:
            return False
        if sub is not TAPPED:
            return sub.get_publisher_count() > 0
        publishers = {(i.node_namespace, i.node_name) for i in self.get_publishers_info_by_topic(topic)}
        tapping = {(i.node_namespace, i.node_name) for i in self.get_publishers_info_by_topic(self.tap_topic)}
        return bool(publishers) and publishers <= tapping

    def on_tap(self, buf: bytes) -> None:
        found = self.tap_senders.check(graph_senders(self, self.tap_topic)) if self.tap_senders.allowed else None
        if found is not None:
            self.tap_forged += 1
            if self.tap_forged == 1:
                self.get_logger().error(f"tap batches refused: {found.reason}")
        elif self._write_tapped(buf):
            self.tap_batches += 1

    def write_records(self, payload: bytes) -> bool:
        """Record the batch payload of a tap in the same process (NodeTap.sink,
        StreamTap.take_payload); False once the recorder is destroyed."""
        if self.writer is None:
            return False
        if self._write_tapped(payload):
            self.tap_lists += 1
        return True

    def _write_tapped(self, batch) -> bool:
        """A tap batch to the bag in one compiled pass; a malformed one is refused
        whole (counted in tap_errors, reported). The topic table comes from another
        process: a name or type rclpy refuses is not recorded, never raised."""
        try:
            topics, region, count = split_batch(batch)
            channels = [self._tapped_channel(name, msgtype) for name, msgtype in topics]
            written, stamps = self.writer.write_tap_records(region, count, channels)
        except ValueError as exc:
            self.tap_errors += 1
            self.get_logger().error(f"tap batch refused: {exc}")
            return False
        self.stamps.add(written, stamps)
        return True

    def _tapped_channel(self, name: str, msgtype: str) -> int:
        """The channel of a tapped topic; -1 when it is not recorded (then not tried
        again for this type; discovery still records the topic if its publishers
        offer a type that can be)."""
        channel = self.channels.get(name)
        if channel is not None or (name, msgtype) in self.tap_refused or (self.topics and name not in self.topics):
            return -1 if channel is None else channel
        try:
            infos = self.get_publishers_info_by_topic(name)
        except Exception as exc:           # noqa: BLE001 - rclpy's InvalidTopicNameException and the like
            self.get_logger().warning(f"{name!r}: not recorded ({exc})")
            infos, channel = None, None
        if infos is not None:
            channel = self._add_channel(name, msgtype, infos)
        if channel is None:
            self.tap_refused.add((name, msgtype))
            return -1
        self.subscriptions_by_topic.setdefault(name, TAPPED)
        return channel

    def destroy_node(self):
        if self.writer is not None:
            self.writer.close()
            if self.summary_path:
                write_summary(self.summary_path, {
                    "recorded": self.writer.counts, "recorded_stamps": self.steps, "tapped": sorted(self.tapped),
                    "tap_errors": self.tap_errors, "tap_batches": self.tap_batches, "tap_lists": self.tap_lists,
                    "tap_forged": self.tap_forged}, self.get_logger().error)
            self.writer = None
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(RecorderNode, args=args, name="recorder", executor="events"))


if __name__ == "__main__":
    main()
