"""Recording taps (pure, no rclpy): a node keeps a copy of the CDR bytes it publishes
on its per-step streams and hands them to the recorder in batches.

Why: a recorder that subscribes to a 1-2 kHz stream costs the publishing process a
delivery to one more reader per message (a shared-memory push and a wake-up of the
reader's process), on the loop's own critical path. Machine-tool controllers record
the same way (TwinCAT Scope, LinuxCNC halsampler): the cyclic task copies its samples
into a buffer that another task drains. Here a node appends (topic index, publish
time, bytes) to a buffer, ~0.4 us, and publishes it every ``period`` as one
``std_msgs/UInt8MultiArray`` on ``TAP_TOPIC``; the recorder writes each record to its
own topic's channel, exactly as a raw subscription would have received it.

Batch payload (little-endian): ``MAGIC``, u32 topic count, per topic
(u16 length + UTF-8 name, u16 length + UTF-8 type), u32 record count, per record
(u16 topic index, i64 publish time ns, u32 length, the CDR bytes). It travels as the
``data`` of a UInt8MultiArray with an empty layout.
"""

from __future__ import annotations

import struct

from pkm_common.cdr import CDR_LE_HEADER

TAP_TOPIC = "_recorder/tap"                 # hidden (leading underscore), relative: per namespace
MAGIC = b"PKMTAP1\x00"
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_RECORD = struct.Struct("<HqI")
_ARRAY_HEAD = struct.Struct("<4sIII")      # encapsulation, dim count, data_offset, data length


def message_type_name(msg_class) -> str:
    """sensor_msgs.msg.JointState -> 'sensor_msgs/msg/JointState'."""
    return f"{msg_class.__module__.split('.')[0]}/msg/{msg_class.__name__}"


class StreamTap:
    """The records of one node since the last batch, kept as the batch will carry them
    (the record layout of the module docstring) so that taking a batch is one copy."""

    def __init__(self):
        self._index: dict[tuple[str, str], int] = {}
        self._topics: list[tuple[str, str]] = []
        self._records = bytearray()
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def topic_index(self, topic: str, msgtype: str) -> int:
        """The index of (topic, type) in this tap's topic table (added if new)."""
        key = (topic, msgtype)
        index = self._index.get(key)
        if index is None:
            if len(self._topics) > 0xFFFF:
                raise ValueError(f"{TAP_TOPIC}: more than 65536 topics in one tap")
            index = self._index[key] = len(self._topics)
            self._topics.append(key)
        return index

    def add(self, topic: str, msgtype: str, data: bytes, publish_time_ns: int) -> None:
        """One published message: the fully qualified topic, its type, the CDR bytes."""
        self.add_indexed(self.topic_index(topic, msgtype), data, publish_time_ns)

    def add_indexed(self, index: int, data: bytes, publish_time_ns: int) -> None:
        """:meth:`add` for a topic of :meth:`topic_index` (the per-message path)."""
        records = self._records
        records.extend(_RECORD.pack(index, publish_time_ns, len(data)))
        records.extend(data)
        self._count += 1

    def take_payload(self) -> bytes | None:
        """The records so far as a batch payload (MAGIC...; then forgotten), or None
        when there are none: what a recorder in the same process is handed."""
        if not self._count:
            return None
        parts = [MAGIC, _U32.pack(len(self._topics))]
        for topic, msgtype in self._topics:
            for text in (topic, msgtype):
                raw = text.encode()
                parts += [_U16.pack(len(raw)), raw]
        parts += [_U32.pack(self._count), self._records]
        payload = b"".join(parts)
        self._records.clear()
        self._count = 0
        return payload

    def take_batch(self) -> bytes | None:
        """The records so far as the CDR bytes of a UInt8MultiArray (then forgotten),
        or None when there are none."""
        payload = self.take_payload()
        if payload is None:
            return None
        return _ARRAY_HEAD.pack(CDR_LE_HEADER, 0, 0, len(payload)) + payload


def split_batch(buf) -> tuple[list[tuple[str, str]], memoryview, int]:
    """(topics, records, count) of a batch (the CDR bytes of the UInt8MultiArray, or
    the payload alone): the topic table as (topic, type) pairs, and the records region
    as a memoryview with its record count, unparsed (the recorder packs it into MCAP
    in one compiled pass, pkm_recording.tap_records). ValueError naming what is wrong
    for anything that is not a batch of ``StreamTap``; the records are not checked."""
    data = memoryview(buf).cast("B")
    if bytes(data[:len(MAGIC)]) != MAGIC:
        if len(data) < _ARRAY_HEAD.size:
            raise ValueError(f"{TAP_TOPIC}: {len(data)} bytes, too short for a UInt8MultiArray")
        encapsulation, dims, _, length = _ARRAY_HEAD.unpack_from(data)
        if encapsulation != CDR_LE_HEADER or dims != 0 or len(data) < _ARRAY_HEAD.size + length:
            raise ValueError(f"{TAP_TOPIC}: not a tap batch (encapsulation {encapsulation!r}, {dims} layout "
                             f"dimensions, data length {length} in {len(data)} bytes)")
        data = data[_ARRAY_HEAD.size:_ARRAY_HEAD.size + length]
        if bytes(data[:len(MAGIC)]) != MAGIC:
            raise ValueError(f"{TAP_TOPIC}: bad magic {bytes(data[:len(MAGIC)])!r}, expected {MAGIC!r}")
    try:
        offset = len(MAGIC)
        (count,), offset = _U32.unpack_from(data, offset), offset + 4
        topics = []
        for _ in range(count):
            texts = []
            for _ in range(2):
                (size,), offset = _U16.unpack_from(data, offset), offset + 2
                if offset + size > len(data):
                    raise ValueError(f"{TAP_TOPIC}: truncated topic table")
                texts.append(bytes(data[offset:offset + size]).decode())
                offset += size
            topics.append(tuple(texts))
        (count,), offset = _U32.unpack_from(data, offset), offset + 4
    except (struct.error, UnicodeDecodeError) as exc:
        raise ValueError(f"{TAP_TOPIC}: truncated or malformed batch ({exc})") from None
    return topics, data[offset:], count


def read_batch(buf) -> list[tuple[str, str, int, bytes]]:
    """The records of a batch: (topic, type, publish time ns, CDR bytes). ValueError
    naming what is wrong for anything that is not a batch of ``StreamTap``. (Python,
    one tuple per record: for tests and tools; the recorder packs the records region
    of :func:`split_batch` directly.)"""
    topics, data, count = split_batch(buf)
    offset, records = 0, []
    try:
        for _ in range(count):
            index, time_ns, size = _RECORD.unpack_from(data, offset)
            offset += _RECORD.size
            if offset + size > len(data) or index >= len(topics):
                raise ValueError(f"{TAP_TOPIC}: record {len(records)}: topic index {index} of {len(topics)}, "
                                 f"{size} bytes at {offset} of {len(data)}")
            topic, msgtype = topics[index]
            records.append((topic, msgtype, time_ns, bytes(data[offset:offset + size])))
            offset += size
    except struct.error as exc:
        raise ValueError(f"{TAP_TOPIC}: truncated or malformed batch ({exc})") from None
    return records


class TappedPublisher:
    """A publisher of CDR bytes whose every message also goes into a ``StreamTap``
    (the node's per-step streams when it is recorded)."""

    __slots__ = ("publisher", "tap", "topic", "msgtype", "clock", "index")

    def __init__(self, publisher, tap: StreamTap, msgtype: str, clock):
        self.publisher, self.tap, self.msgtype, self.clock = publisher, tap, msgtype, clock
        self.topic = publisher.topic_name
        self.index = tap.topic_index(self.topic, msgtype)

    def publish(self, data: bytes) -> None:
        self.publisher.publish(data)
        self.tap.add_indexed(self.index, data, self.clock())
