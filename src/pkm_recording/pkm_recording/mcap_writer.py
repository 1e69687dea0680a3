"""mcap's ``Writer`` with a message path ~5x faster (pure, no rclpy).

Why: the recorder writes every message of the loop (7 per step of archi_demo, i.e.
~7,000/s), and in mcap 1.6's Python writer one ``add_message`` costs ~6 us: a
``Message`` dataclass, five ``struct.pack`` calls into a ``BytesIO`` with a seek back
for the record length, a ``MessageIndex`` entry, and at chunk end a Python loop of two
more packs per message for the index. In the in-process mode the recorder shares the
loop's thread, so that cost is on the loop's period.

``FastWriter`` is ``mcap.writer.Writer`` (header, schemas, channels, chunk compression,
chunk indexes, statistics, summary, footer: all unchanged) with two parts replaced:

* each Message record (opcode 0x05, u64 length, u16 channel id, u32 sequence, u64
  log time, u64 publish time, data; MCAP spec) is packed with one ``struct.pack`` into
  the ``bytearray`` of a :class:`FastChunkBuilder`, a batch of them in one call
  (``add_messages``);
* its message indexes write their (log time, offset) pairs with one ``struct.pack``;
* ``add_packed`` takes Message records already packed by the recorder's compiled
  pass (pkm_recording.tap_records) and appends them per batch.

It reaches into the writer's private attributes (``_Writer__...``); mcap is pinned in
requirements.txt, and tests/recording/test_mcap_writer.py compares the output with the
stock writer byte for byte, so an mcap upgrade that changes them fails there first.
With an mcap whose Writer lacks one of them (another install), it falls back to the
stock path. An mcap that kept the names but changed what they mean would not be
noticed here: only the byte-identical test would show it.
"""

from __future__ import annotations

import struct

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, MessageIndex, Schema
from mcap.writer import Writer

from pkm_recording.tap_records import index_packed_segment

__all__ = ["FastChunkBuilder", "FastWriter"]

# Message record: opcode, record length, channel id, sequence, log time, publish time
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIELDS = _MESSAGE_HEAD.size - 9      # the 22 bytes before the data
_INDEX_HEAD = struct.Struct("<BQHI")


def _span(count: int, start: int, end: int, t_min: int, t_max: int) -> tuple[int, int]:
    """(start, end) log times after more messages with log times in [t_min, t_max]
    (``count`` before them); as mcap's ``min``/``max`` updates, with the first message
    setting both."""
    if count == 0:
        return t_min, t_max
    return (t_min if t_min < start else start), (t_max if t_max > end else end)


class _FastMessageIndex(MessageIndex):
    """A MessageIndex record whose (timestamp, offset) pairs are kept flat (time,
    offset, time, ...) in ``flat`` and packed in one call (``records`` stays empty)."""

    def __init__(self, channel_id: int):
        super().__init__(channel_id=channel_id, records=[])
        self.flat: list[int] = []

    def write(self, stream: RecordBuilder):
        flat = self.flat
        stream.write(_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + 8 * len(flat), self.channel_id, 8 * len(flat)))
        if flat:
            stream.write(struct.pack(f"<{len(flat)}Q", *flat))


class FastChunkBuilder:
    """Stands in for ``mcap._chunk_builder.ChunkBuilder`` (the attributes and methods
    the Writer uses once ``add_message`` is FastWriter's): a ``bytearray`` that
    :meth:`FastWriter.add_messages` packs the Message records into and
    :meth:`FastWriter.add_packed` appends packed ones to."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.message_indices: dict[int, _FastMessageIndex] = {}
        self.message_start_time = 0
        self.message_end_time = 0
        self.num_messages = 0

    @property
    def count(self) -> int:
        return len(self._buffer)

    def end(self) -> bytes:
        data = bytes(self._buffer)
        self._buffer = bytearray()
        return data

    def _add_record(self, record) -> None:
        builder = RecordBuilder()
        record.write(builder)
        self._buffer += builder.end()

    def add_channel(self, channel: Channel) -> None:
        self._add_record(channel)

    def add_schema(self, schema: Schema) -> None:
        self._add_record(schema)

    def reset(self) -> None:
        self._buffer = bytearray()
        self.message_indices = {}
        self.message_start_time = self.message_end_time = 0
        self.num_messages = 0


class FastWriter(Writer):
    """``mcap.writer.Writer`` (chunked; the arguments are the same) with the fast
    message path. ``add_message`` takes the same arguments and writes the same bytes."""

    # what the fast path uses of mcap 1.6's Writer
    PRIVATE = ("_Writer__chunk_builder", "_Writer__statistics", "_Writer__chunk_size", "_Writer__finalize_chunk")

    def __init__(self, *args, **kwargs):
        if kwargs.get("use_chunking", True) is False:
            raise ValueError("FastWriter writes chunks: use_chunking must be True")
        super().__init__(*args, **kwargs)
        if getattr(self, "_Writer__chunk_builder", True) is None:        # use_chunking=False, positional
            raise ValueError("FastWriter writes chunks: use_chunking must be True")
        self.fast = all(hasattr(self, name) for name in self.PRIVATE)
        if self.fast:
            self._Writer__chunk_builder = FastChunkBuilder()

    def add_message(self, channel_id: int, log_time: int, data, publish_time: int, sequence: int = 0):
        if not self.fast:
            return super().add_message(channel_id, log_time, data, publish_time, sequence)
        self.add_messages(((channel_id, log_time, data, publish_time, sequence),))

    def add_messages(self, messages) -> None:
        """``add_message(*m)`` for each m = (channel id, log time, data, publish time,
        sequence) of ``messages``, in order, and the same bytes; one call for a batch
        (~1.4 instead of ~2.5 us a message). The recorder's tap batches, already
        packed, go to :meth:`add_packed`."""
        if not self.fast:
            for message in messages:
                super().add_message(*message)
            return
        stats = self._Writer__statistics
        counts, limit = stats.channel_message_counts, self._Writer__chunk_size
        chunk = self._Writer__chunk_builder
        pack, opcode = _MESSAGE_HEAD.pack, Opcode.MESSAGE
        n, start, end = stats.message_count, stats.message_start_time, stats.message_end_time
        try:
            for channel_id, log_time, data, publish_time, sequence in messages:
                start, end = _span(n, start, end, log_time, log_time)
                n += 1
                counts[channel_id] += 1
                buffer = chunk._buffer
                offset = len(buffer)
                size = len(data) if type(data) is bytes else memoryview(data).nbytes
                buffer += pack(opcode, _MESSAGE_FIELDS + size, channel_id, sequence, log_time, publish_time)
                buffer += data
                index = chunk.message_indices.get(channel_id)
                if index is None:
                    index = chunk.message_indices[channel_id] = _FastMessageIndex(channel_id)
                index.flat += (log_time, offset)
                chunk.message_start_time, chunk.message_end_time = _span(
                    chunk.num_messages, chunk.message_start_time, chunk.message_end_time, log_time, log_time)
                chunk.num_messages += 1
                if len(buffer) > limit:
                    stats.message_count, stats.message_start_time, stats.message_end_time = n, start, end
                    self._Writer__finalize_chunk()
        finally:
            stats.message_count, stats.message_start_time, stats.message_end_time = n, start, end

    def add_packed(self, records, channels, times, ends) -> tuple[int, int] | None:
        """Message records already packed back to back (pkm_recording.tap_records:
        ``records`` a uint8 array, per record its channel id, log time and end offset
        in ``records``), with the same bytes as :meth:`add_message` for each in order
        (chunk ends included): the chunk buffer takes them in slices, the indexes and
        statistics per batch. Returns the (earliest, latest) log time of the records,
        None for none."""
        if not len(ends):
            return None
        if not self.fast:
            return self._add_packed_one_by_one(records, channels, times, ends)
        stats, limit = self._Writer__statistics, self._Writer__chunk_size
        view = memoryview(records).cast("B")
        channels, times = np.asarray(channels, dtype=np.int64), np.asarray(times, dtype=np.int64)
        ends = np.asarray(ends, dtype=np.int64)
        lo, total, counts, span = 0, len(ends), stats.channel_message_counts, None
        while lo < total:
            chunk = self._Writer__chunk_builder
            hi, pairs, group_channels, bounds, t_min, t_max = index_packed_segment(
                channels, times, ends, lo, len(chunk._buffer), limit)
            chunk._buffer += view[int(ends[lo - 1]) if lo else 0:int(ends[hi - 1])]
            flat, bounds = pairs.ravel().tolist(), bounds.tolist()
            for g, channel_id in enumerate(group_channels.tolist()):
                index = chunk.message_indices.get(channel_id)
                if index is None:
                    index = chunk.message_indices[channel_id] = _FastMessageIndex(channel_id)
                index.flat += flat[2 * bounds[g]:2 * bounds[g + 1]]
                counts[channel_id] += bounds[g + 1] - bounds[g]
            hi, t_min, t_max = int(hi), int(t_min), int(t_max)          # Python ints (numpy's without numba)
            m = hi - lo
            chunk.message_start_time, chunk.message_end_time = _span(
                chunk.num_messages, chunk.message_start_time, chunk.message_end_time, t_min, t_max)
            chunk.num_messages += m
            stats.message_start_time, stats.message_end_time = _span(
                stats.message_count, stats.message_start_time, stats.message_end_time, t_min, t_max)
            stats.message_count += m
            span = _span(0 if span is None else 1, *(span or (0, 0)), t_min, t_max)
            lo = hi
            if len(chunk._buffer) > limit:
                self._Writer__finalize_chunk()
        return span

    def _add_packed_one_by_one(self, records, channels, times, ends) -> tuple[int, int]:
        view, start = memoryview(records).cast("B"), 0
        for channel_id, end in zip(np.asarray(channels).tolist(), np.asarray(ends).tolist()):
            _, _, _, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(view, start)
            super().add_message(channel_id, log_time, bytes(view[start + _MESSAGE_HEAD.size:end]), publish_time,
                                sequence)
            start = end
        return int(np.min(times)), int(np.max(times))
