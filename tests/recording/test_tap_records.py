"""The compiled tap-record packer against the Python batch reader and the MCAP spec."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_recording.tap_records import PACK_BAD_CHANNEL, PACK_OK, StampCounter, pack_tap_records
from pkm_recording.tap import StreamTap, read_batch, split_batch

TOPICS = ["/drives/state", "/metrology/struts", "/clock"]
RECORDS = st.lists(st.tuples(st.sampled_from(TOPICS), st.binary(max_size=80), st.integers(0, 2**63 - 1)),
                   max_size=40)
CHANNELS = st.lists(st.sampled_from([-1, 1, 2, 5]), min_size=3, max_size=3)


def _stamp(data: bytes) -> int:
    return int.from_bytes(data[4:12], "little", signed=True) if len(data) >= 12 else -1 - len(data)


@settings(max_examples=100, deadline=None)
@given(RECORDS, CHANNELS, st.integers(0, 2**32 - 1))
def test_packed_records_are_the_mcap_messages_of_the_batch(records, channel_of_topic, first_sequence):
    tap = StreamTap()
    for topic, data, time_ns in records:
        tap.add(topic, "sensor_msgs/msg/JointState", data, time_ns)
    payload = tap.take_payload()
    if payload is None:
        return
    topics, region, count = split_batch(payload)
    channel_of = np.array([channel_of_topic[TOPICS.index(t)] for t, _ in topics], np.int64)
    sequence = np.full(6, first_sequence, np.int64)
    out, channels, times, ends, stamps, per_topic, code, _ = pack_tap_records(np.frombuffer(bytearray(region), np.uint8),
                                                                   count, channel_of, sequence)
    assert code == PACK_OK
    expected, next_sequence = [], {}
    for topic, _, time_ns, data in read_batch(payload):       # the Python reader: the reference
        channel = channel_of_topic[TOPICS.index(topic)]
        if channel >= 0:
            next_sequence[channel] = (next_sequence.get(channel, first_sequence) + 1) % 2**32
            expected.append((channel, next_sequence[channel], time_ns, data))
    got, start = [], 0
    for end in ends.tolist():                                 # MCAP Message records, by the spec
        opcode, length, channel, seq, log_time, publish_time = struct.unpack_from("<BQHIQQ", out, start)
        assert opcode == 0x05 and length == end - start - 9 and publish_time == log_time
        got.append((channel, seq, log_time, bytes(out[start + 31:end])))
        start = end
    assert start == len(out) and got == expected
    assert channels.tolist() == [c for c, _, _, _ in expected] and times.tolist() == [t for _, _, t, _ in expected]
    assert stamps.tolist() == [_stamp(d) for _, _, _, d in expected]
    assert all(sequence[c] == s for c, s in next_sequence.items())
    assert per_topic.tolist() == [sum(1 for t, _, _, _ in read_batch(payload) if t == name and c >= 0)
                                  for (name, _), c in zip(topics, channel_of.tolist())]


def test_the_stamp_counter_counts_changes_per_channel_across_batches():
    counter = StampCounter(channels=2)
    counter.reserve(3)
    counter.add(np.array([1, 1, 3, 1], np.int64), np.array([5, 5, 5, 6], np.int64))
    counter.reserve(70)
    counter.add(np.array([1, 3, 70], np.int64), np.array([6, 7, 0], np.int64))
    assert [counter.count(c) for c in (0, 1, 3, 70, 999)] == [0, 2, 2, 1, 0]
    with pytest.raises(ValueError, match="channel 999: not reserved"):
        counter.add(np.array([999], np.int64), np.array([0], np.int64))


def test_a_channel_outside_the_sequence_table_is_refused_before_anything_is_written():
    tap = StreamTap()
    tap.add("/clock", "rosgraph_msgs/msg/Clock", bytes(12), 5)
    _, region, count = split_batch(tap.take_payload())
    region = np.frombuffer(bytearray(region), np.uint8)
    for channel, size in ((3, 3), (70_000, 70_001)):          # past the table; past u16
        sequence = np.zeros(size, np.int64)
        out, *_, code, record = pack_tap_records(region, count, np.array([channel], np.int64), sequence)
        assert (code, record, len(out)) == (PACK_BAD_CHANNEL, 0, 0) and not sequence.any()


def test_the_stamp_a_recorder_counts_is_the_packers():
    """record_stamp (Python, for a run kept in memory) and pack_tap_records (compiled, the
    bag's) give a message the same stamp, a header's and a short message's."""
    import numpy as np

    from pkm_recording.tap import StreamTap, split_batch
    from pkm_recording.tap_records import pack_tap_records, record_stamp
    messages = [bytes([0, 1, 0, 0]) + (123).to_bytes(4, "little") + (456).to_bytes(4, "little", signed=False) + b"x",
                bytes([0, 1, 0, 0]) + (-5).to_bytes(4, "little", signed=True) + (7).to_bytes(4, "little") + b"yz",
                bytes([0, 1, 0, 0, 1])]                      # a Bool: shorter than a header
    tap = StreamTap()
    index = tap.topic_index("/t", "std_msgs/msg/Bool")
    for k, raw in enumerate(messages):
        tap.add_indexed(index, raw, 1000 + k)
    _, region, count = split_batch(tap.take_payload())
    stamps = pack_tap_records(np.frombuffer(bytearray(region), np.uint8), count, np.array([0], np.int64),
                              np.zeros(1, np.int64))[4]
    assert stamps.tolist() == [record_stamp(raw) for raw in messages]
    assert record_stamp(messages[2]) == -6 and record_stamp(messages[0]) == 123 + (456 << 32)
