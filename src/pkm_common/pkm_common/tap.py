"""Recording taps (pure, no rclpy): a node keeps a copy of the CDR bytes it publishes
on its per-step streams and hands them to the recorder in batches.

Why: a recorder that subscribes to a 1-2 kHz stream costs the publishing process a
delivery to one more reader per message (a shared-memory push and a wake-up of the
reader's process), on the loop's own critical path. Machine-tool controllers record
the same way (TwinCAT Scope, LinuxCNC halsampler): the cyclic task copies its samples
into a buffer that another task drains. Here a node appends (topic, type, publish
time, bytes) to a list, ~1 us, and publishes the list every ``period`` as one
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
    """The records of one node since the last batch."""

    def __init__(self):
        self._index: dict[tuple[str, str], int] = {}
        self._topics: list[tuple[str, str]] = []
        self._records: list[tuple[int, int, bytes]] = []

    def __len__(self) -> int:
        return len(self._records)

    def add(self, topic: str, msgtype: str, data: bytes, publish_time_ns: int) -> None:
        """One published message: the fully qualified topic, its type, the CDR bytes."""
        key = (topic, msgtype)
        index = self._index.get(key)
        if index is None:
            index = self._index[key] = len(self._topics)
            self._topics.append(key)
        self._records.append((index, publish_time_ns, data))

    def take_records(self) -> list[tuple[str, str, int, bytes]]:
        """The records so far as :func:`read_batch` returns them (then forgotten): for a
        recorder in the same process, which needs no batch message."""
        topics, records = self._topics, self._records
        self._records = []
        return [(*topics[index], time_ns, data) for index, time_ns, data in records]

    def take_batch(self) -> bytes | None:
        """The records so far as the CDR bytes of a UInt8MultiArray (then forgotten),
        or None when there are none."""
        if not self._records:
            return None
        parts = [MAGIC, _U32.pack(len(self._topics))]
        for topic, msgtype in self._topics:
            for text in (topic, msgtype):
                raw = text.encode()
                parts += [_U16.pack(len(raw)), raw]
        parts.append(_U32.pack(len(self._records)))
        pack = _RECORD.pack
        for index, time_ns, data in self._records:
            parts += [pack(index, time_ns, len(data)), data]
        self._records = []
        payload = b"".join(parts)
        return _ARRAY_HEAD.pack(CDR_LE_HEADER, 0, 0, len(payload)) + payload


def read_batch(buf) -> list[tuple[str, str, int, bytes]]:
    """The records of a batch: (topic, type, publish time ns, CDR bytes). ValueError
    naming what is wrong for anything that is not a batch of ``StreamTap``."""
    buf = bytes(buf)
    if len(buf) < _ARRAY_HEAD.size:
        raise ValueError(f"{TAP_TOPIC}: {len(buf)} bytes, too short for a UInt8MultiArray")
    encapsulation, dims, _, length = _ARRAY_HEAD.unpack_from(buf)
    if encapsulation != CDR_LE_HEADER or dims != 0 or len(buf) < _ARRAY_HEAD.size + length:
        raise ValueError(f"{TAP_TOPIC}: not a tap batch (encapsulation {encapsulation!r}, {dims} layout "
                         f"dimensions, data length {length} in {len(buf)} bytes)")
    data = memoryview(buf)[_ARRAY_HEAD.size:_ARRAY_HEAD.size + length]
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
                texts.append(bytes(data[offset:offset + size]).decode())
                offset += size
            topics.append(tuple(texts))
        (count,), offset = _U32.unpack_from(data, offset), offset + 4
        records = []
        for _ in range(count):
            index, time_ns, size = _RECORD.unpack_from(data, offset)
            offset += _RECORD.size
            if offset + size > len(data) or index >= len(topics):
                raise ValueError(f"{TAP_TOPIC}: record {len(records)}: topic index {index} of {len(topics)}, "
                                 f"{size} bytes at {offset} of {len(data)}")
            topic, msgtype = topics[index]
            records.append((topic, msgtype, time_ns, bytes(data[offset:offset + size])))
            offset += size
    except (struct.error, UnicodeDecodeError) as exc:
        raise ValueError(f"{TAP_TOPIC}: truncated or malformed batch ({exc})") from None
    return records


class TappedPublisher:
    """A publisher of CDR bytes whose every message also goes into a ``StreamTap``
    (the node's per-step streams when it is recorded)."""

    __slots__ = ("publisher", "tap", "topic", "msgtype", "clock")

    def __init__(self, publisher, tap: StreamTap, msgtype: str, clock):
        self.publisher, self.tap, self.msgtype, self.clock = publisher, tap, msgtype, clock
        self.topic = publisher.topic_name

    def publish(self, data: bytes) -> None:
        self.publisher.publish(data)
        self.tap.add(self.topic, self.msgtype, data, self.clock())
