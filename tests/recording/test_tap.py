"""The recording tap's batch format against rclpy's own UInt8MultiArray serialisation."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import UInt8MultiArray

from pkm_recording.tap import MAGIC, StreamTap, TappedPublisher, message_type_name, read_batch, split_batch

RECORDS = st.lists(st.tuples(st.sampled_from(["/drives/state", "/ns/metrology/struts", "/clock"]),
                             st.sampled_from(["sensor_msgs/msg/JointState", "rosgraph_msgs/msg/Clock"]),
                             st.binary(max_size=300), st.integers(-2**63, 2**63 - 1)), max_size=40)


@settings(max_examples=100, deadline=None)
@given(RECORDS)
def test_a_batch_reads_back_in_order_and_is_a_valid_uint8_multiarray(records):
    tap = StreamTap()
    for topic, msgtype, data, time_ns in records:
        tap.add(topic, msgtype, data, time_ns)
    assert len(tap) == len(records)
    batch = tap.take_batch()
    if not records:
        assert batch is None
        return
    assert len(tap) == 0 and tap.take_batch() is None            # taken once
    assert read_batch(batch) == [(t, m, ns, d) for t, m, d, ns in records]
    msg = deserialize_message(batch, UInt8MultiArray)             # rclpy reads our CDR
    assert bytes(msg.data).startswith(MAGIC) and not msg.layout.dim
    assert serialize_message(msg) == batch                        # and writes the same bytes


@settings(max_examples=50, deadline=None)
@given(RECORDS)
def test_a_payload_taken_in_process_is_what_the_batch_carries(records):
    by_batch, by_payload = StreamTap(), StreamTap()
    for tap in (by_batch, by_payload):
        for topic, msgtype, data, time_ns in records:
            tap.add(topic, msgtype, data, time_ns)
    payload = by_payload.take_payload()
    if not records:
        assert payload is None
        return
    batch = by_batch.take_batch()
    assert batch.endswith(payload) and read_batch(payload) == read_batch(batch)
    assert split_batch(payload)[1:] == split_batch(batch)[1:]
    assert len(by_payload) == 0 and by_payload.take_payload() is None


def test_a_malformed_batch_is_refused_naming_the_tap():
    tap = StreamTap()
    tap.add("/drives/state", "sensor_msgs/msg/JointState", b"\x00\x01\x00\x00abcd", 5)
    batch = tap.take_batch()
    for bad, why in ((batch[:10], "too short"), (batch[:-2], "not a tap batch"),
                     (serialize_message(UInt8MultiArray(data=b"x" * 20)), "bad magic")):
        with pytest.raises(ValueError, match=f"_recorder/tap: .*{why}"):
            read_batch(bad)
    cut = bytearray(batch)
    cut[-8 - 4:-8] = (1 << 20).to_bytes(4, "little")               # a record longer than the batch
    with pytest.raises(ValueError, match="_recorder/tap: record 0"):
        read_batch(bytes(cut))


def test_a_tapped_publisher_publishes_and_records_the_same_bytes():
    class Publisher:
        topic_name = "/ns/drives/state"
        sent = []

        def publish(self, data):
            self.sent.append(data)
    tap = StreamTap()
    pub = TappedPublisher(Publisher(), tap, message_type_name(JointState), lambda: 42)
    pub.publish(b"\x00\x01\x00\x00xyz")
    assert Publisher.sent == [b"\x00\x01\x00\x00xyz"]
    assert read_batch(tap.take_batch()) == [("/ns/drives/state", "sensor_msgs/msg/JointState", 42,
                                             b"\x00\x01\x00\x00xyz")]


def test_a_node_tap_publishes_batches_and_drops_one_on_a_dead_context():
    import rclpy
    from rclpy.node import Node

    from pkm_recording.node_tap import NodeTap
    from pkm_common.qos import STREAM_PUBLISHER_QOS
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("tap_test", context=context)
    try:
        assert NodeTap(node, False).wrap("publisher", JointState) == "publisher"     # off: nothing added
        tap = NodeTap(node, True)
        pub = tap.wrap(node.create_publisher(JointState, "x", STREAM_PUBLISHER_QOS), JointState)
        pub.publish(b"\x00\x01\x00\x00" + bytes(40))
        tap.flush()
        tap.flush()                                                 # nothing new: no batch
        assert (tap.batches, tap.dropped) == (1, 0)
        pub.publish(b"\x00\x01\x00\x00" + bytes(40))
    finally:
        rclpy.shutdown(context=context)
    tap.flush()                                                     # the teardown goes on
    assert (tap.batches, tap.dropped) == (1, 1)
    node.destroy_node()


def test_a_node_tap_with_a_sink_hands_its_records_over_without_a_message():
    import rclpy
    from rclpy.node import Node

    from pkm_recording.node_tap import NodeTap
    from pkm_common.qos import STREAM_PUBLISHER_QOS
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("tap_sink_test", context=context)
    try:
        tap = NodeTap(node, True)
        received, batches = [], []
        tap.sink = received.append
        tap.publisher = type("Publisher", (), {"publish": lambda self, batch: batches.append(batch)})()
        raw = tap.wrap(node.create_publisher(JointState, "y", STREAM_PUBLISHER_QOS), JointState)
        data = b"\x00\x01\x00\x00" + bytes(40)
        raw.publish(data)
        raw.publish(data)
        tap.flush()
        tap.close()                                                 # nothing new: no second list
        assert tap.batches == 1 and batches == []                   # handed over, no message
        assert [[(t, m, d) for t, m, _, d in read_batch(r)] for r in received] == [
            [("/y", "sensor_msgs/msg/JointState", data)] * 2]
        raw.publish(data)
        tap.sink = lambda records: False                           # the recorder is gone
        tap.flush()
        raw.publish(data)
        tap.sink = lambda records: 1 / 0                           # the recorder fails
        tap.flush()
        assert (tap.batches, tap.dropped, batches) == (1, 2, [])
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
