"""Recording-tap records to MCAP Message records in one compiled pass (pure, no rclpy).

The recorder receives a node's tap records as one region of bytes (pkm_recording.tap:
per record u16 topic index, i64 publish time ns, u32 length, the CDR bytes). Turning
them into MCAP Message records (opcode 0x05, u64 record length, u16 channel id, u32
sequence, u64 log time, u64 publish time, the data; MCAP spec) one Python tuple at a
time cost ~5 us a message in the loop's context (a parse, three tuples, the checks,
the pack, the header-stamp count); in the in-process mode that is on the loop's own
thread, ~4 % of its period for archi_demo's 7 messages a step.

:func:`pack_tap_records` checks the whole region first (nothing is written from a
malformed one), then writes every Message record into one array; the MCAP writer
appends it (``FastWriter.add_packed``) and :class:`StampCounter` counts the messages
with a new header stamp, both per batch, not per message.
"""

from __future__ import annotations

import numpy as np

from pkm_kinematics.jit import kernel

TAP_RECORD_HEAD = 14                 # u16 topic index, i64 publish time, u32 length
MESSAGE_HEAD = 31                    # opcode, u64 length, u16 channel, u32 sequence, u64 log, u64 publish time
MESSAGE_OPCODE = 0x05
# pack_tap_records outcome codes
PACK_OK, PACK_TRUNCATED, PACK_UNKNOWN_TOPIC, PACK_NEGATIVE_TIME, PACK_BAD_CHANNEL = range(5)
PACK_ERRORS = {PACK_TRUNCATED: "record {k} runs past the end of the batch",
               PACK_UNKNOWN_TOPIC: "record {k} names a topic index the batch does not list",
               PACK_NEGATIVE_TIME: "record {k} has a negative publish time",
               PACK_BAD_CHANNEL: "record {k}: its channel id is outside the sequence table or above 65535"}


@kernel()
def _read_le(buf, offset, size):
    """The little-endian integer of ``size`` bytes at ``offset`` (two's complement for 8)."""
    value = 0
    for k in range(size - 1, -1, -1):
        value = (value << 8) | int(buf[offset + k])
    if size == 8 and value > 0 and buf[offset + 7] >= 0x80:
        value = value - (1 << 63) - (1 << 63)        # interpreted: Python ints do not wrap at 64 bits
    return value


@kernel()
def _write_le(buf, offset, value, size):
    for k in range(size):
        buf[offset + k] = (value >> (8 * k)) & 0xFF


@kernel()
def _nothing_packed(code, record):
    empty = np.zeros(0, np.int64)
    return np.zeros(0, np.uint8), empty, empty.copy(), empty.copy(), empty.copy(), empty.copy(), code, record


@kernel("(uint8[:], int64, int64[:], int64[:])")
def pack_tap_records(region, count, channel_of, sequence):
    """(out, channels, times, ends, stamps, per_topic, code, record): the ``count`` tap
    records of ``region`` as MCAP Message records, back to back in ``out``.

    ``channel_of[i]``: the channel id of the tap's topic index i, -1 to skip its
    records. ``sequence[c]``: the last sequence number of channel c, advanced (mod
    2**32) for each record written. Per record written: its channel, its log time (=
    its publish time), the end of its Message record in ``out``, and its header stamp
    (CDR bytes 4-12 as an int64: std_msgs/Header and rosgraph_msgs/Clock start with it;
    a message shorter than 12 bytes stands in with -1 - its length); ``per_topic``: the
    records written per topic index. ``code`` PACK_OK, or what is wrong with record number ``record``: then nothing is
    written and ``sequence`` is unchanged."""
    size = region.shape[0]
    offset, written, out_size = 0, 0, 0
    per_topic = np.zeros(channel_of.shape[0], np.int64)
    for k in range(count):
        if offset + TAP_RECORD_HEAD > size:
            return _nothing_packed(PACK_TRUNCATED, k)
        index, length = _read_le(region, offset, 2), _read_le(region, offset + 10, 4)
        offset += TAP_RECORD_HEAD + length
        code = PACK_OK
        if offset > size:
            code = PACK_TRUNCATED
        elif index >= channel_of.shape[0]:
            code = PACK_UNKNOWN_TOPIC
        elif channel_of[index] >= 0:
            if region[offset - length - 5] >= 0x80:      # the sign byte of the i64 time
                code = PACK_NEGATIVE_TIME
            elif channel_of[index] >= sequence.shape[0] or channel_of[index] > 0xFFFF:
                code = PACK_BAD_CHANNEL
            written += 1
            per_topic[index] += 1
            out_size += MESSAGE_HEAD + length
        if code != PACK_OK:
            return _nothing_packed(code, k)
    out = np.empty(out_size, np.uint8)
    channels, times = np.empty(written, np.int64), np.empty(written, np.int64)
    ends, stamps = np.empty(written, np.int64), np.empty(written, np.int64)
    offset, position, w = 0, 0, 0
    for k in range(count):
        index, time_ns, length = _read_le(region, offset, 2), _read_le(region, offset + 2, 8), \
            _read_le(region, offset + 10, 4)
        data = offset + TAP_RECORD_HEAD
        offset = data + length
        channel = channel_of[index]
        if channel < 0:
            continue
        seq = (sequence[channel] + 1) & 0xFFFFFFFF
        sequence[channel] = seq
        out[position] = MESSAGE_OPCODE
        _write_le(out, position + 1, MESSAGE_HEAD - 9 + length, 8)
        _write_le(out, position + 9, channel, 2)
        _write_le(out, position + 11, seq, 4)
        _write_le(out, position + 15, time_ns, 8)
        _write_le(out, position + 23, time_ns, 8)
        out[position + MESSAGE_HEAD:position + MESSAGE_HEAD + length] = region[data:data + length]
        position += MESSAGE_HEAD + length
        channels[w], times[w], ends[w] = channel, time_ns, position
        stamps[w] = _read_le(region, data + 4, 8) if length >= 12 else -1 - length
        w += 1
    return out, channels, times, ends, stamps, per_topic, PACK_OK, -1


@kernel("(int64[:], int64[:], int64[:], int64, int64, int64)")
def index_packed_segment(channels, times, ends, lo, base, limit):
    """The part of a packed batch that goes into the open chunk, and its message
    indexes: from record ``lo`` on, up to and including the record that takes the
    chunk (``base`` bytes before it) past ``limit`` bytes, as MCAP's writer closes a
    chunk after the message that crosses its size. Returns (hi, pairs, group_channels,
    group_bounds, t_min, t_max): records lo..hi-1; their (log time, offset in the
    chunk) pairs grouped by channel, in message order within a group, the groups in
    the order of their channel's first message; group g is pairs[group_bounds[g]:
    group_bounds[g + 1]] of channel group_channels[g]; the segment's time span."""
    n = channels.shape[0]
    first = ends[lo - 1] if lo > 0 else 0
    hi = n
    for k in range(lo, n):
        if base + ends[k] - first > limit:
            hi = k + 1
            break
    m = hi - lo
    top = 0
    for k in range(lo, hi):
        top = max(top, channels[k])
    group_of = np.full(top + 1, -1, np.int64)
    group_channels = np.empty(m, np.int64)
    sizes = np.zeros(m + 1, np.int64)
    groups = 0
    t_min, t_max = times[lo], times[lo]
    for k in range(lo, hi):
        c = channels[k]
        if group_of[c] < 0:
            group_of[c] = groups
            group_channels[groups] = c
            groups += 1
        sizes[group_of[c] + 1] += 1
        t_min, t_max = min(t_min, times[k]), max(t_max, times[k])
    bounds = np.cumsum(sizes[:groups + 1])
    fill = bounds[:groups].copy()
    pairs = np.empty((m, 2), np.int64)
    for k in range(lo, hi):
        g = group_of[channels[k]]
        pairs[fill[g], 0] = times[k]
        pairs[fill[g], 1] = base + (ends[k - 1] if k > 0 else 0) - first
        fill[g] += 1
    return hi, pairs, group_channels[:groups].copy(), bounds, t_min, t_max


@kernel("(int64[:], int64[:], int64[:], boolean[:], int64[:])")
def _count_new_stamps(channels, stamps, last, seen, counts):
    """The count of each record whose stamp differs from its channel's last one; -1,
    or the first channel id outside the arrays (nothing counted from it on)."""
    for k in range(channels.shape[0]):
        c, s = channels[k], stamps[k]
        if not 0 <= c < counts.shape[0]:
            return c
        if not seen[c] or last[c] != s:
            seen[c], last[c] = True, s
            counts[c] += 1
    return -1


def record_stamp(raw) -> int:
    """The stamp a recorder counts a message by (pack_tap_records' rule, in Python): the
    8 bytes after the CDR header (a header's sec and nanosec) as one little-endian
    int64, or -1 - its length for a message shorter than 12 bytes (a Bool)."""
    return int.from_bytes(raw[4:12], "little", signed=True) if len(raw) >= 12 else -1 - len(raw)


class StampCounter:
    """Per channel id, the messages with a new header stamp (a repeat of the last
    stamp is not counted: sim_hw republishes step 0 until it is answered), as the
    recorder reports them against what the nodes published. One thread (the
    recorder's executor): ``reserve`` replaces the arrays ``add`` works on."""

    def __init__(self, channels: int = 64):
        self.last = np.zeros(channels, np.int64)
        self.seen = np.zeros(channels, bool)
        self.counts = np.zeros(channels, np.int64)

    def reserve(self, channel: int) -> None:
        """Make room for channel ids up to ``channel`` (when a channel is added)."""
        if channel >= len(self.counts):
            grow = max(channel + 1, 2 * len(self.counts)) - len(self.counts)
            self.last = np.concatenate([self.last, np.zeros(grow, np.int64)])
            self.seen = np.concatenate([self.seen, np.zeros(grow, bool)])
            self.counts = np.concatenate([self.counts, np.zeros(grow, np.int64)])

    def add(self, channels: np.ndarray, stamps: np.ndarray) -> None:
        """The records written, as :func:`pack_tap_records` returns them (their
        channels reserved: ValueError naming one that is not)."""
        outside = _count_new_stamps(channels, stamps, self.last, self.seen, self.counts)
        if outside >= 0:
            raise ValueError(f"channel {outside}: not reserved in the stamp counter (0..{len(self.counts) - 1})")

    def add_one(self, channel: int, stamp: int) -> None:
        """One message of ``channel`` (reserved) stamped ``stamp``: a subscription's,
        outside a tap batch."""
        if not self.seen[channel] or self.last[channel] != stamp:
            self.seen[channel], self.last[channel] = True, stamp
            self.counts[channel] += 1

    def count(self, channel: int) -> int:
        return int(self.counts[channel]) if 0 <= channel < len(self.counts) else 0
