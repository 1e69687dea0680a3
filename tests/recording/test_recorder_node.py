"""recorder_node in a test process: discovery pace, the in-process tap hand-over and
the chunk compression."""

from __future__ import annotations

import pytest
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from rclpy.parameter import Parameter
from rosbags.highlevel import AnyReader

from pkm_recording.recorder_node import RecorderNode
from pkm_common.params import ParameterError
from pkm_recording.tap import StreamTap


def _recorder(ctx, tmp_path, name, **params):
    overrides = [Parameter(k, value=v) for k, v in {"output": str(tmp_path / name), **params}.items()]
    return RecorderNode(context=ctx, namespace="/rec_test", parameter_overrides=overrides)


def test_discovery_slows_down_once_the_recorder_is_ready(ros_context, tmp_path):
    waiting = _recorder(ros_context, tmp_path, "a", expect_topics="never/published")
    ready = _recorder(ros_context, tmp_path, "b", running_discovery_period_s=2.5)
    try:
        assert not waiting.ready and waiting.discovery_timer.timer_period_ns == 100_000_000
        assert ready.ready and ready.discovery_timer.timer_period_ns == 2_500_000_000
    finally:
        waiting.destroy_node()
        ready.destroy_node()


def _payload(records) -> bytes:
    """A tap's batch payload of (topic, type, publish time ns, CDR bytes) records."""
    tap = StreamTap()
    for topic, msgtype, time_ns, data in records:
        tap.add(topic, msgtype, data, time_ns)
    return tap.take_payload()


def _clock(sec: int) -> bytes:
    return b"\x00\x01\x00\x00" + sec.to_bytes(4, "little") + (0).to_bytes(4, "little")


def test_records_handed_over_are_written_and_refused_once_destroyed(ros_context, tmp_path):
    """Written and counted per new stamp (a repeat of a stamp is recorded, not counted);
    a malformed batch is refused whole and counted as a tap error."""
    node = _recorder(ros_context, tmp_path, "c")
    clock = "rosgraph_msgs/msg/Clock"
    try:
        assert node.write_records(_payload([("/clock", clock, 7_000_000_000, _clock(7)),
                                            ("/clock", clock, 7_000_000_001, _clock(7)),
                                            ("/clock", clock, 8_000_000_000, _clock(8))])) is True
        assert node.writer.counts["/clock"] == 3 and node.steps["/clock"] == 2
        assert node.write_records(_payload([("/clock", clock, 9_000_000_000, _clock(8))])[:-3]) is True
        assert node.tap_errors == 1 and node.writer.counts["/clock"] == 3
    finally:
        node.destroy_node()
    assert node.write_records(_payload([("/clock", clock, 8_000_000_000, _clock(9))])) is False


def test_a_tap_batch_naming_a_bad_topic_or_type_is_not_recorded_and_does_not_stop_the_node(ros_context, tmp_path):
    """The topic table comes from another process: an invalid topic name (rclpy
    refuses it) or a type that is not a message type name is skipped and remembered,
    the other topics of the batch are recorded."""
    node = _recorder(ros_context, tmp_path, "e")
    clock = "rosgraph_msgs/msg/Clock"
    try:
        batch = _payload([("/bad name", clock, 1, _clock(1)), ("/x", "../msg/Evil", 2, _clock(2)),
                          ("/clock", clock, 3, _clock(3))])
        assert node.write_records(batch) is True and node.write_records(batch) is True
        counts = node.writer.counts
        assert counts["/clock"] == 2 and "/bad name" not in counts and "/x" not in counts
        assert node.tap_lists == 2 and node.tap_errors == 0
        assert node.tap_refused == {("/bad name", clock), ("/x", "../msg/Evil")}
    finally:
        node.destroy_node()


def _chunk_compressions(bag_dir) -> set:
    with open(next(bag_dir.glob("*.mcap")), "rb") as fh:
        return {r.compression for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, Chunk)}


@pytest.mark.parametrize("compression", [None, "zstd", "none"])
def test_chunks_are_lz4_unless_another_compression_is_asked_for(ros_context, tmp_path, compression):
    params = {} if compression is None else {"compression": compression}
    node = _recorder(ros_context, tmp_path, "d", **params)
    clock = [b"\x00\x01\x00\x00" + k.to_bytes(4, "little") + (0).to_bytes(4, "little") for k in range(50)]
    try:
        node.write_records(_payload([("/clock", "rosgraph_msgs/msg/Clock", k * 10**9, c) for k, c in enumerate(clock)]))
    finally:
        node.destroy_node()
    assert _chunk_compressions(tmp_path / "d") == {{None: "lz4", "zstd": "zstd", "none": ""}[compression]}
    with AnyReader([tmp_path / "d"]) as reader:                  # rosbags reads it back, byte for byte
        assert [(t, bytes(raw)) for _, t, raw in reader.messages()] == [(k * 10**9, c) for k, c in enumerate(clock)]


def test_an_unknown_compression_is_refused_by_name(ros_context, tmp_path):
    with pytest.raises(ParameterError, match="compression.*lz4"):
        _recorder(ros_context, tmp_path, "e", compression="bz2")
    assert not (tmp_path / "e").exists()


def test_only_the_runs_namespace_and_the_global_topics_are_recorded(ros_context, tmp_path):
    """A run beside another one in namespace /ns2 of the same domain records only its own."""
    from rclpy.node import Node
    from std_msgs.msg import String

    from pkm_common.qos import STREAM_QOS
    rec = _recorder(ros_context, tmp_path, "ns")
    mine = Node("mine", namespace="/rec_test", context=ros_context)
    other = Node("other", namespace="/ns2", context=ros_context)
    try:
        for node in (mine, other):
            node.create_publisher(String, "chatter", STREAM_QOS)
        mine.create_publisher(String, "/rosout_like_global", STREAM_QOS)
        import time
        end = time.monotonic() + 5.0
        while "/rec_test/chatter" not in rec.subscriptions_by_topic and time.monotonic() < end:
            rec.discover()
            time.sleep(0.05)
        rec.discover()
        assert "/rec_test/chatter" in rec.subscriptions_by_topic
        assert "/ns2/chatter" not in rec.subscriptions_by_topic
        assert "/rosout_like_global" not in rec.subscriptions_by_topic
        assert rec.in_scope("/clock") and rec.in_scope("/rosout")
    finally:
        for node in (mine, other, rec):
            node.destroy_node()


def test_a_tap_batch_while_a_node_not_named_publishes_on_the_tap_is_refused(ros_context, tmp_path):
    """A forged batch on the tap topic would be recorded as the graph's own data: while
    a node not in tap_sources publishes there, batches are refused whole and counted."""
    import time

    from rclpy.serialization import serialize_message
    from std_msgs.msg import UInt8MultiArray

    from pkm_common.qos import TAP_QOS
    from pkm_recording.tap import TAP_TOPIC
    node = _recorder(ros_context, tmp_path, "f", tapped_topics="/clock", tap_sources="/rec_test/sim_hw")
    rogue = __import__("rclpy").create_node("rogue", namespace="/rec_test", context=ros_context)
    clock = "rosgraph_msgs/msg/Clock"
    try:
        rogue.create_publisher(UInt8MultiArray, TAP_TOPIC, TAP_QOS)
        deadline = time.monotonic() + 10
        while not node.get_publishers_info_by_topic(node.tap_topic) and time.monotonic() < deadline:
            time.sleep(0.02)
        forged = serialize_message(UInt8MultiArray(data=_payload([("/clock", clock, 5, _clock(5))])))
        node.on_tap(forged)
        assert node.tap_forged == 1 and node.tap_batches == 0 and "/clock" not in node.writer.counts
        # without names (a recorder started by hand) it is taken, as before
        open_node = _recorder(ros_context, tmp_path, "g", tapped_topics="/clock")
        try:
            open_node.on_tap(forged)
            assert open_node.tap_batches == 1 and open_node.writer.counts["/clock"] == 1
        finally:
            open_node.destroy_node()
    finally:
        rogue.destroy_node()
        node.destroy_node()
