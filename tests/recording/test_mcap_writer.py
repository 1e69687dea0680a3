"""FastWriter against mcap's own Writer: the same calls must give the same bytes."""

from __future__ import annotations

import io
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from pkm_recording.mcap_writer import FastWriter

# one call of a recording: ("msg", channel, log time, size, publish offset, sequence) or ("flush",)
_message = st.tuples(st.just("msg"), st.integers(1, 3), st.integers(0, 2**40), st.integers(0, 300),
                     st.integers(0, 10**6), st.integers(0, 2**32 - 1))
_calls = st.lists(st.one_of(_message, st.just(("flush",))), max_size=120)


def _packed(batch) -> tuple:
    """Message records packed back to back as pkm_recording.tap_records makes them
    (MCAP spec: opcode 0x05, u64 length, u16 channel, u32 sequence, u64 log and publish
    time, data), with their channels, log times and end offsets."""
    parts, ends, end = [], [], 0
    for channel, log_time, data, publish_time, sequence in batch:
        parts.append(struct.pack("<BQHIQQ", 0x05, 22 + len(data), channel, sequence, log_time, publish_time)
                     + bytes(data))
        end += len(parts[-1])
        ends.append(end)
    return (np.frombuffer(b"".join(parts), np.uint8), np.array([m[0] for m in batch], np.int64),
            np.array([m[1] for m in batch], np.int64), np.array(ends, np.int64))


def _record(writer_class, calls, chunk_size, compression, data_kind=bytes, batched=False, packed=False) -> bytes:
    """The bytes of a recording; ``batched``: the messages between two flushes go to
    ``add_messages`` in one call; ``packed``: to ``add_packed``, packed beforehand."""
    batched = batched or packed
    out = io.BytesIO()
    writer = writer_class(out, chunk_size=chunk_size, compression=compression)
    writer.start(profile="ros2", library="test")
    schema = writer.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
    for topic in ("/a", "/b", "/c"):
        writer.register_channel(topic, "cdr", schema, {"offered_qos_profiles": ""})
    batch = []
    for call in calls:
        if call[0] == "flush":
            if batch:
                writer.add_packed(*_packed(batch)) if packed else writer.add_messages(batch)
                batch = []
            writer.flush()
            continue
        _, channel, log_time, size, publish_offset, sequence = call
        data = bytes((log_time + i) & 0xFF for i in range(size))
        message = (channel, log_time, data_kind(data), log_time + publish_offset, sequence)
        if batched:
            batch.append(message)
        else:
            writer.add_message(*message)
    if batch:                                      # the last batch, in the chunk finish() closes
        writer.add_packed(*_packed(batch)) if packed else writer.add_messages(batch)
    writer.finish()
    return out.getvalue()


@settings(max_examples=60, deadline=None)
@given(calls=_calls, chunk_size=st.sampled_from([64, 1000, 1 << 20]),
       compression=st.sampled_from([CompressionType.NONE, CompressionType.ZSTD, CompressionType.LZ4]))
def test_the_same_calls_give_the_same_bytes_as_mcaps_writer(calls, chunk_size, compression):
    assert FastWriter(io.BytesIO()).fast          # the pinned mcap: the fast path, not the fallback
    expected = _record(Writer, calls, chunk_size, compression)
    assert _record(FastWriter, calls, chunk_size, compression) == expected
    assert _record(FastWriter, calls, chunk_size, compression, data_kind=memoryview) == expected
    assert _record(FastWriter, calls, chunk_size, compression, batched=True) == expected
    assert _record(FastWriter, calls, chunk_size, compression, packed=True) == expected


def test_what_it_writes_reads_back_in_order_with_the_summary():
    calls = [("msg", 1 + k % 3, 1000 + 7 * k, 20 + k % 5, 3, k) for k in range(500)]
    data = _record(FastWriter, calls, 2000, CompressionType.ZSTD)
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    assert summary.statistics.message_count == 500
    assert dict(summary.statistics.channel_message_counts) == {1: 167, 2: 167, 3: 166}
    assert (summary.statistics.message_start_time, summary.statistics.message_end_time) == (1000, 1000 + 7 * 499)
    assert len(summary.chunk_indexes) > 5
    messages = [(m.channel_id, m.log_time, m.sequence, m.publish_time, len(m.data))
                for _, _, m in reader.iter_messages(log_time_order=False)]
    assert messages == [(c, t, s, t + 3, n) for _, c, t, n, _, s in calls]


def test_without_the_private_attributes_it_falls_back_to_the_stock_path(monkeypatch):
    calls = [("msg", 1 + k % 3, 10 * k, 30, 1, k) for k in range(50)] + [("flush",)]
    expected = _record(Writer, calls, 500, CompressionType.ZSTD)
    monkeypatch.setattr(FastWriter, "PRIVATE", FastWriter.PRIVATE + ("_Writer__renamed_in_a_later_mcap",))
    assert not FastWriter(io.BytesIO()).fast
    assert _record(FastWriter, calls, 500, CompressionType.ZSTD) == expected
    assert _record(FastWriter, calls, 500, CompressionType.ZSTD, batched=True) == expected
    assert _record(FastWriter, calls, 500, CompressionType.ZSTD, packed=True) == expected


def test_it_refuses_to_write_without_chunks():
    with pytest.raises(ValueError, match="use_chunking"):
        FastWriter(io.BytesIO(), use_chunking=False)
    with pytest.raises(ValueError, match="use_chunking"):     # the same, positional
        FastWriter(io.BytesIO(), 1024, CompressionType.NONE, IndexType.ALL, True, True, False)
