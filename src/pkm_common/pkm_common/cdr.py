"""Serialized (CDR) form of the per-step messages, without rclpy message objects.

The lockstep loop exchanges a handful of small messages per step. Through rclpy's
message objects each costs a deserialization on take (JointState ~30 us, PoseStamped
~50 us: nested Python objects with checking setters) and a serialization on publish
(~13 us), more than the control law itself. A raw subscription (``raw=True``) hands
the callback the CDR bytes and ``Publisher.publish`` accepts bytes; this module reads
and writes those bytes directly with precompiled ``struct`` layouts (~1-3 us), so the
topics keep their standard types (sensor_msgs/JointState, geometry_msgs/PoseStamped,
rosgraph_msgs/Clock) and every other tool still reads them.

Format (OMG XCDR1, as rmw_fastrtps writes it): a 4-byte encapsulation header
(``00 01 00 00``: CDR little endian), then the fields in order, each primitive
aligned to its own size relative to the byte after the header; a string is a uint32
length counting its NUL, the bytes and the NUL; a sequence is a uint32 count then the
elements (no alignment padding when the count is 0). Bytes after the last field are
ignored (rmw's buffers are often longer than the message).

A malformed buffer raises ValueError naming the field; nothing else is checked here
(finite values, lengths per name and quaternion norms are the caller's rules, as for
a message object).
"""

from __future__ import annotations

import operator
import struct
from typing import NamedTuple

import numpy as np

from pkm_kinematics.errors import FieldError

CDR_LE_HEADER = b"\x00\x01\x00\x00"
_HEADER_AND_STAMP = struct.Struct("<4siI")          # encapsulation, stamp.sec, stamp.nanosec
_UINT32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
NS_PER_S = 1_000_000_000


class JointStateData(NamedTuple):
    """The fields of a sensor_msgs/JointState; stamp as integer nanoseconds."""
    stamp_ns: int
    frame_id: str
    name: tuple
    position: tuple
    velocity: tuple
    effort: tuple


class PoseStampedData(NamedTuple):
    """The fields of a geometry_msgs/PoseStamped: position (x, y, z), orientation (x, y, z, w)."""
    stamp_ns: int
    frame_id: str
    position: tuple
    orientation: tuple


def in_order(msg: JointStateData, names, what: str = "JointState") -> JointStateData:
    """``msg`` with its arrays in the order of ``names``. A message without names is
    taken to be in that order already; an array of another length than the names is
    left as it is (the caller checks lengths). ValueError naming ``what`` when the
    names are not a permutation of ``names``."""
    names = names if isinstance(names, (list, tuple)) else tuple(names)
    if len(msg.name) == 0 or msg.name == names or tuple(msg.name) == tuple(names):
        return msg
    got, names = list(msg.name), list(names)
    if sorted(got) != sorted(names):
        raise FieldError(what, f"names {got} are not {names}")
    order = [got.index(n) for n in names]

    def pick(values):
        return tuple(values[i] for i in order) if len(values) == len(order) else values
    return msg._replace(name=tuple(names), position=pick(msg.position), velocity=pick(msg.velocity),
                        effort=pick(msg.effort))


def _pad(offset: int, alignment: int) -> int:
    """Padding bytes before a field of ``alignment`` at ``offset`` (relative to the body)."""
    return -offset % alignment


def _stamp_ns(sec: int, nanosec: int, what: str) -> int:
    """A received stamp as nanoseconds; before 1970 or a nanosec of a second or more is
    refused (ValueError): it is no time of a run, and answered it cannot be encoded."""
    if sec < 0 or nanosec >= NS_PER_S:
        raise FieldError(what, f"header.stamp must be at or after 0 s with nanosec < 1e9, got sec {sec}, "
                               f"nanosec {nanosec}")
    return sec * NS_PER_S + nanosec


def _split_stamp(stamp_ns: int) -> tuple[int, int]:
    sec, nanosec = divmod(stamp_ns, NS_PER_S)
    if not 0 <= sec < 2**31:
        raise FieldError("stamp", f"must be in [0, 2^31 s) as nanoseconds, got {stamp_ns}")
    return sec, nanosec


def _string_bytes(text: str, offset: int) -> tuple[bytes, int]:
    """CDR of a string field starting at body ``offset``: (bytes incl. padding, new offset)."""
    raw = text.encode("utf-8") + b"\x00"
    pad = _pad(offset, 4)
    out = b"\x00" * pad + _UINT32.pack(len(raw)) + raw
    return out, offset + len(out)


# ------------------------------------------------------------------- reading
class _Reader:
    """Sequential CDR reader over one buffer; offsets relative to the body (after the header)."""

    __slots__ = ("buf", "pos", "what")

    def __init__(self, buf, what: str, minimum: int = 12):
        if len(buf) < minimum or bytes(buf[:4]) != CDR_LE_HEADER:
            raise FieldError(what, f"not a little-endian CDR message "
                                   f"(header {bytes(buf[:4]).hex()}, {len(buf)} bytes)")
        self.buf, self.pos, self.what = buf, 4, what

    def _need(self, size: int, field: str) -> None:
        if self.pos + size > len(self.buf):
            raise ValueError(f"{self.what}: {field} runs past the end of the message "
                             f"({len(self.buf)} bytes)")

    def align(self, alignment: int) -> None:
        self.pos += _pad(self.pos - 4, alignment)

    def uint32(self, field: str) -> int:
        self.align(4)
        self._need(4, field)
        value = _UINT32.unpack_from(self.buf, self.pos)[0]
        self.pos += 4
        return value

    def string(self, field: str) -> str:
        size = self.uint32(field)
        self._need(size, field)
        raw = bytes(self.buf[self.pos:self.pos + size])
        if size == 0 or raw[-1] != 0:
            raise ValueError(f"{self.what}: {field} is not a NUL-terminated string")
        self.pos += size
        try:
            return raw[:-1].decode("utf-8")
        except UnicodeDecodeError:
            raise ValueError(f"{self.what}: {field} is not UTF-8") from None

    def doubles(self, count: int, field: str) -> tuple:
        if count == 0:
            return ()
        self.align(8)
        self._need(8 * count, field)
        values = struct.unpack_from(f"<{count}d", self.buf, self.pos)
        self.pos += 8 * count
        return values

    def double_sequence(self, field: str) -> tuple:
        return self.doubles(self.uint32(f"{field} count"), field)

    def stamp_ns(self, checked: bool = True) -> int:
        self._need(8, "header.stamp")
        sec, nanosec = _STAMP.unpack_from(self.buf, self.pos)
        self.pos += 8
        return _stamp_ns(sec, nanosec, self.what) if checked else sec * NS_PER_S + nanosec


def stamp_ns_of(buf) -> int:
    """header.stamp (or Clock.clock) of a serialized stamped message, as nanoseconds:
    the first field of the body, unchecked: the recorder and a bag's recovery read it
    of every message, stamped or not (what acts on a stamp decodes it, checked)."""
    return _Reader(buf, "message").stamp_ns(checked=False)


def decode_joint_state(buf, what: str = "JointState") -> JointStateData:
    """Fields of a serialized sensor_msgs/JointState. ``what`` names the topic in errors."""
    r = _Reader(buf, what)
    stamp = r.stamp_ns()
    frame_id = r.string("header.frame_id")
    count = r.uint32("name count")
    if count > len(buf):
        raise FieldError(what, f"name count {count} exceeds the message size")
    name = tuple(r.string(f"name[{i}]") for i in range(count))
    return JointStateData(stamp, frame_id, name, r.double_sequence("position"),
                          r.double_sequence("velocity"), r.double_sequence("effort"))


def decode_pose_stamped(buf, what: str = "PoseStamped") -> PoseStampedData:
    """Fields of a serialized geometry_msgs/PoseStamped."""
    r = _Reader(buf, what)
    stamp = r.stamp_ns()
    frame_id = r.string("header.frame_id")
    values = r.doubles(7, "pose")
    return PoseStampedData(stamp, frame_id, values[:3], values[3:])


def decode_wrench_stamped(buf, what: str = "WrenchStamped") -> tuple[tuple, tuple]:
    """(force, torque) of a serialized geometry_msgs/WrenchStamped."""
    r = _Reader(buf, what)
    r.stamp_ns()
    r.string("header.frame_id")
    values = r.doubles(6, "wrench")
    return values[:3], values[3:]


class TrajectoryData(NamedTuple):
    """The fields of a trajectory_msgs/MultiDOFJointTrajectory as arrays: N points, J
    joints. ``transform[k, j]`` = translation (x, y, z) + rotation (x, y, z, w);
    ``velocity`` and ``acceleration`` [k, j] = linear (x, y, z) + angular (x, y, z),
    zero where a point has none; ``time_s`` = time_from_start in seconds."""
    stamp_ns: int
    frame_id: str
    joint_names: tuple
    time_s: np.ndarray
    transform: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


# One point of one joint with its transform, velocity and acceleration, starting 8-byte
# aligned (every point after the first of such a trajectory is): counts, the doubles
# after 4 bytes of padding, time_from_start; 184 bytes, a multiple of 8.
_POINT_1 = np.dtype({"names": ["nt", "tf", "nv", "vel", "na", "acc", "sec", "nsec"],
                     "formats": ["<u4", ("<f8", 7), "<u4", ("<f8", 6), "<u4", ("<f8", 6), "<i4", "<u4"],
                     "offsets": [0, 8, 64, 72, 120, 128, 176, 180], "itemsize": 184})


def decode_multidof_trajectory(buf, what: str = "trajectory") -> TrajectoryData:
    """Fields of a serialized trajectory_msgs/MultiDOFJointTrajectory.

    rclpy's message objects take ~65 us per point to build (a 400-point trajectory held
    a realtime loop 26 ms); the points of a one-joint trajectory with a velocity and
    an acceleration per point (as trajectory_node publishes) are read here as one numpy
    record array. Any other layout takes the field-by-field path. ValueError names
    the field of a malformed message, or the point whose counts do not match the joints.
    """
    r = _Reader(buf, what)
    stamp = r.stamp_ns()
    frame_id = r.string("header.frame_id")
    count = r.uint32("joint_names count")
    if count > len(buf):
        raise FieldError(what, f"joint_names count {count} exceeds the message size")
    names = tuple(r.string(f"joint_names[{i}]") for i in range(count))
    n = r.uint32("points count")
    if n > len(buf) // 8:
        raise FieldError(what, f"points count {n} exceeds the message size")
    j = len(names)
    t, tf, vel, acc = np.zeros(n), np.zeros((n, j, 7)), np.zeros((n, j, 6)), np.zeros((n, j, 6))
    first = r.pos
    if j == 1 and n > 1:
        _read_point(r, 0, j, t, tf, vel, acc)          # the first point, then all the others at once
        if (r.pos - 4) % 8 == 0 and r.pos + _POINT_1.itemsize * (n - 1) <= len(buf):
            rec = np.frombuffer(buf, _POINT_1, count=n - 1, offset=r.pos)
            if (rec["nt"] == 1).all() and (rec["nv"] == 1).all() and (rec["na"] == 1).all():
                t[1:] = rec["sec"] + 1e-9 * rec["nsec"]
                tf[1:, 0], vel[1:, 0], acc[1:, 0] = rec["tf"], rec["vel"], rec["acc"]
                return TrajectoryData(stamp, frame_id, names, t, tf, vel, acc)
        r.pos = first                                  # another layout: every point in turn
    for k in range(n):
        _read_point(r, k, j, t, tf, vel, acc)
    return TrajectoryData(stamp, frame_id, names, t, tf, vel, acc)


def encode_multidof_trajectory(stamp_ns: int, frame_id: str, joint: str, time_s, transforms, velocities,
                               accelerations) -> bytes:
    """A serialized trajectory_msgs/MultiDOFJointTrajectory of one joint (as
    trajectory_node publishes): point k has the transform ``transforms[k]`` (x, y, z,
    qx, qy, qz, qw), one velocity and one acceleration twist (6 each) and
    time_from_start ``time_s[k]`` rounded to the nanosecond; the bytes rclpy serializes
    for the same message (tests/common/test_cdr.py), made as one record array instead
    of ~65 us of message objects per point."""
    time_s = np.asarray(time_s, dtype=float)
    n = len(time_s)
    sec, nanosec = _split_stamp(stamp_ns)
    frame, offset = _string_bytes(frame_id, 8)
    pad = _pad(offset, 4)
    name, offset = _string_bytes(joint, offset + pad + 4)
    head = [CDR_LE_HEADER, _STAMP.pack(sec, nanosec), frame, b"\x00" * pad, _UINT32.pack(1), name]
    pad = _pad(offset, 4)
    head += [b"\x00" * pad, _UINT32.pack(n)]
    offset += pad + 4
    ns = np.rint(time_s * 1e9).astype(np.int64)           # round(t * 1e9), half to even as Python's
    if n and ((ns < 0).any() or (ns // NS_PER_S >= 2**31).any()):
        raise FieldError("time_s", "time_from_start must be in [0, 2^31 s)")
    rec = np.zeros(n, _POINT_1)
    rec["nt"], rec["nv"], rec["na"] = 1, 1, 1
    rec["tf"], rec["vel"], rec["acc"] = transforms, velocities, accelerations
    rec["sec"], rec["nsec"] = ns // NS_PER_S, ns % NS_PER_S
    if not n:
        return b"".join(head)
    # the first point where it falls (4 or 8 past an alignment of 8); then every point
    # starts aligned, 184 bytes apart (_POINT_1)
    first = rec[:1].tobytes()
    if offset % 8 == 4:                      # its transforms aligned without the padding after their count;
        first = first[:4] + first[8:]        # the other fields' paddings fall as in the records
    return b"".join(head) + first + rec[1:].tobytes()


def _read_point(r: _Reader, k: int, joints: int, t, tf, vel, acc) -> None:
    """Point ``k`` into the arrays: one transform per joint; velocities and
    accelerations one per joint or none (MultiDOFJointTrajectoryPoint)."""
    field = f"points[{k}]"
    for name, width, out, allowed in (("transforms", 7, tf, (joints,)), ("velocities", 6, vel, (0, joints)),
                                      ("accelerations", 6, acc, (0, joints))):
        count = r.uint32(f"{field}.{name} count")
        if count not in allowed:
            raise ValueError(f"{r.what}: {field}.{name}: expected {' or '.join(map(str, allowed))} "
                             f"(one per joint), got {count}")
        if count:
            out[k] = np.reshape(r.doubles(width * count, f"{field}.{name}"), (count, width))
    r.align(4)
    r._need(8, f"{field}.time_from_start")
    sec, nanosec = _STAMP.unpack_from(r.buf, r.pos)
    r.pos += 8
    t[k] = sec + 1e-9 * nanosec


class JointStateDecoder:
    """``decode_joint_state`` with the layout of the last message remembered: a stream
    from one publisher (same names, frame and array lengths every step) is read with
    one compare and one ``struct`` call; any other message takes the general path."""

    def __init__(self, what: str = "JointState"):
        self.what = what
        self._layout: JointStateEncoder | None = None

    def decode(self, buf) -> JointStateData:
        lay = self._layout
        if lay is not None and len(buf) >= lay.size:
            values = lay._struct.unpack_from(buf)
            if values[0] == CDR_LE_HEADER and values[3] == lay._middle \
                    and lay._count_getter(values) == lay._count_values:
                sec, nanosec = values[1], values[2]
                if sec < 0 or nanosec >= NS_PER_S:
                    _stamp_ns(sec, nanosec, self.what)       # raises, naming it
                return JointStateData(sec * NS_PER_S + nanosec, lay.frame_id, lay.names, *lay._array_getter(values))
        data = decode_joint_state(buf, self.what)
        n = len(data.name)
        fields = [f for f, values in zip(JointStateEncoder.FIELDS, data[3:]) if values]
        if all(len(values) in (0, n) for values in data[3:]):
            self._layout = JointStateEncoder(data.name, data.frame_id, fields)
        else:
            self._layout = None
        return data


# ------------------------------------------------------------------- writing
class JointStateEncoder:
    """Serialized sensor_msgs/JointState of fixed names and frame: the layout is
    compiled once, ``encode`` packs a stamp and the arrays in one ``struct`` call.

    ``fields``: which of position, velocity, effort carry one value per name (the
    others are empty sequences, as in a command that only sets efforts).
    """

    FIELDS = ("position", "velocity", "effort")

    def __init__(self, names, frame_id: str = "", fields=FIELDS):
        names = [str(n) for n in names]
        unknown = set(fields) - set(self.FIELDS)
        if unknown:
            raise FieldError("fields", f"must be among {list(self.FIELDS)}, got {sorted(unknown)}")
        self.names, self.frame_id, self.n = tuple(names), frame_id, len(names)
        self.fields = tuple(f for f in self.FIELDS if f in fields)
        offset = 8                                        # body offset after the stamp
        middle, offset = _string_bytes(frame_id, offset)
        pad = _pad(offset, 4)
        middle += b"\x00" * pad + _UINT32.pack(len(names))
        offset += pad + 4
        for name in names:
            chunk, offset = _string_bytes(name, offset)
            middle += chunk
        fmt = ["<4siI", f"{len(middle)}s"]
        self.offsets = {}                                 # field -> byte offset of its first double in a message
        for field in self.FIELDS:
            pad = _pad(offset, 4)
            fmt.append(f"{pad}xI")
            offset += pad + 4
            if field in self.fields and self.n:
                pad = _pad(offset, 8)
                fmt.append(f"{pad}x{self.n}d")
                self.offsets[field] = len(CDR_LE_HEADER) + offset + pad
                offset += pad + 8 * self.n
        self._middle = middle
        self._struct = struct.Struct("".join(fmt))
        self._counts = {f: (self.n if f in self.fields else 0) for f in self.FIELDS}
        # (argument of encode, field, count) in the message's order: encode's loop (~0.25 us less than by name)
        self._plan = tuple((i, f, self._counts[f]) for i, f in enumerate(self.FIELDS))
        # (index of each array's count in the unpacked tuple, the count); the array
        # follows its count (JointStateDecoder)
        index, self._count_index = 4, []
        for field in self.FIELDS:
            self._count_index.append((index, self._counts[field]))
            index += 1 + self._counts[field]
        # what JointStateDecoder reads of an unpacked message in this layout: the counts
        # (to compare with these) and the arrays, each one C call
        self._count_getter = operator.itemgetter(*(i for i, _ in self._count_index))
        self._count_values = tuple(count for _, count in self._count_index)
        self._array_getter = operator.itemgetter(*(slice(i + 1, i + 1 + count) for i, count in self._count_index))
        self.size = self._struct.size
        # encode's one-pack forms (~0.3 us less than its loop): every field, or one (its
        # index, the empty counts before and after it); else (-1) the loop
        self._pack = self._struct.pack
        one = [i for i, f in enumerate(self.FIELDS) if f in self.fields]
        self._one = one[0] if len(one) == 1 and self.n else -1
        self._around = ((0,) * self._one, (0,) * (len(self.FIELDS) - 1 - self._one)) if self._one >= 0 else None
        self._every = len(one) == len(self.FIELDS) and self.n > 0

    def template(self) -> bytes:
        """A message of this layout stamped 0 with zeros: what a kernel writes the stamp
        and the arrays into (pkm_common.cdr_kernels, at ``offsets``)."""
        zeros = [0.0] * self.n
        return self.encode(0, *(zeros if field in self.fields else () for field in self.FIELDS))

    def encode(self, stamp_ns: int, position=(), velocity=(), effort=()) -> bytes:
        """Bytes of the message; each array of ``fields`` must hold one value per name."""
        sec, nanosec = divmod(stamp_ns, NS_PER_S)
        if not 0 <= sec < 2**31:
            _split_stamp(stamp_ns)                        # raises, naming it
        n = self.n
        try:
            if self._every and len(position) == n and len(velocity) == n and len(effort) == n:
                return self._pack(CDR_LE_HEADER, sec, nanosec, self._middle, n, *position, n, *velocity, n, *effort)
            if self._one >= 0:
                values = (position, velocity, effort)[self._one]
                if len(values) == n:
                    before, after = self._around
                    return self._pack(CDR_LE_HEADER, sec, nanosec, self._middle, *before, n, *values, *after)
        except struct.error as exc:
            raise ValueError(f"JointState: {exc} (the arrays must hold numbers)") from None
        arrays = (position, velocity, effort)
        args = [CDR_LE_HEADER, sec, nanosec, self._middle]
        for i, field, count in self._plan:
            args.append(count)
            if count:
                values = arrays[i]
                if len(values) != count:
                    raise ValueError(f"{field}: expected {count} values (one per name), got {len(values)}")
                args += values
        try:
            return self._struct.pack(*args)
        except struct.error as exc:
            raise ValueError(f"JointState: {exc} (the arrays must hold numbers)") from None


class PoseStampedEncoder:
    """Serialized geometry_msgs/PoseStamped of a fixed frame."""

    def __init__(self, frame_id: str = "world"):
        self.frame_id = frame_id
        middle, offset = _string_bytes(frame_id, 8)
        pad = _pad(offset, 8)
        self._struct = struct.Struct(f"<4siI{len(middle)}s{pad}x7d")
        self._middle = middle
        self.size = self._struct.size
        # the byte offset of position then orientation, 7 doubles (pkm_common.cdr_kernels)
        self.values_offset = len(CDR_LE_HEADER) + offset + pad

    def matches(self, buf) -> bool:
        """Whether ``buf`` is a message of this layout (its size, header and frame):
        then its stamp and values are at fixed offsets."""
        return len(buf) == self.size and buf[12:12 + len(self._middle)] == self._middle and \
            buf[:4] == CDR_LE_HEADER

    def encode(self, stamp_ns: int, position, orientation) -> bytes:
        """``position`` (x, y, z) and ``orientation`` (x, y, z, w) as numbers."""
        sec, nanosec = divmod(stamp_ns, NS_PER_S)
        if not 0 <= sec < 2**31:
            _split_stamp(stamp_ns)                        # raises, naming it
        px, py, pz = position
        qx, qy, qz, qw = orientation
        return self._struct.pack(CDR_LE_HEADER, sec, nanosec, self._middle, px, py, pz, qx, qy, qz, qw)


class PoseStampedDecoder:
    """``decode_pose_stamped`` with the layout of one frame's messages (PoseStampedEncoder's):
    a stream in that frame is read with one compare and one ``struct`` call; any other
    message takes the general path."""

    def __init__(self, frame_id: str = "world", what: str = "PoseStamped"):
        self.frame_id, self.what = frame_id, what
        self._layout = PoseStampedEncoder(frame_id)

    def decode(self, buf) -> PoseStampedData:
        lay = self._layout
        if len(buf) == lay.size:
            v = lay._struct.unpack_from(buf)
            if v[0] == CDR_LE_HEADER and v[3] == lay._middle:
                if v[1] < 0 or v[2] >= NS_PER_S:
                    _stamp_ns(v[1], v[2], self.what)         # raises, naming it
                return PoseStampedData(v[1] * NS_PER_S + v[2], self.frame_id, v[4:7], v[7:11])
        return decode_pose_stamped(buf, self.what)


def encode_string(text: str) -> bytes:
    """Serialized std_msgs/String."""
    middle, _ = _string_bytes(text, 0)
    return CDR_LE_HEADER + middle


def decode_string(buf, what: str = "String") -> str:
    """``data`` of a serialized std_msgs/String."""
    return _Reader(buf, what, minimum=9).string("data")


def decode_bool(buf, what: str = "Bool") -> bool:
    """``data`` of a serialized std_msgs/Bool."""
    if len(buf) < 5 or bytes(buf[:4]) != CDR_LE_HEADER:
        raise FieldError(what, f"not a little-endian CDR std_msgs/Bool ({len(buf)} bytes)")
    return buf[4] != 0


def first_string_span(buf, stamped: bool, what: str = "message") -> tuple[int, int]:
    """Byte offsets [start, end) of the first string's characters, its NUL excluded:
    ``header.frame_id`` of a stamped message (``stamped``), else the first field
    (std_msgs/String ``data``). The string is checked as the decoders check it."""
    r = _Reader(buf, what, minimum=9)
    if stamped:
        r.stamp_ns(checked=False)
    start = r.pos + _pad(r.pos - 4, 4) + 4
    r.string("header.frame_id" if stamped else "data")
    return start, r.pos - 1


def encode_diagnostic_array(stamp_ns: int, statuses, frame_id: str = "") -> bytes:
    """Serialized diagnostic_msgs/DiagnosticArray: ``statuses`` each (level 0-255,
    name, message, hardware_id, [(key, value)] strings), as rclpy serializes the
    message (~20 us here against ~400 us for the message objects and rclpy)."""
    sec, nanosec = _split_stamp(stamp_ns)
    parts = [_HEADER_AND_STAMP.pack(CDR_LE_HEADER, sec, nanosec)]
    chunk, offset = _string_bytes(frame_id, 8)
    parts.append(chunk)
    offset = _count(parts, len(statuses), offset)
    for level, name, message, hardware_id, values in statuses:
        parts.append(bytes((level,)))
        offset += 1
        for text in (name, message, hardware_id):
            chunk, offset = _string_bytes(text, offset)
            parts.append(chunk)
        offset = _count(parts, len(values), offset)
        for key, value in values:
            for text in (key, value):
                chunk, offset = _string_bytes(text, offset)
                parts.append(chunk)
    return b"".join(parts)


def _count(parts: list, count: int, offset: int) -> int:
    """A sequence's uint32 length at body ``offset``, padded; returns the new offset."""
    pad = _pad(offset, 4)
    parts.append(b"\x00" * pad + _UINT32.pack(count))
    return offset + pad + 4


def encode_clock(stamp_ns: int) -> bytes:
    """Serialized rosgraph_msgs/Clock."""
    sec, nanosec = _split_stamp(stamp_ns)
    return _HEADER_AND_STAMP.pack(CDR_LE_HEADER, sec, nanosec)


__all__ = ["CDR_LE_HEADER", "ShownReader", "JointStateData", "JointStateEncoder", "PoseStampedData", "PoseStampedEncoder",
           "JointStateDecoder", "TrajectoryData", "decode_joint_state", "decode_multidof_trajectory", "decode_pose_stamped", "decode_string", "decode_wrench_stamped", "encode_clock", "encode_diagnostic_array", "encode_string",
           "first_string_span", "stamp_ns_of"]


class ShownReader:
    """For a node that only shows what it reads (the panel, the Foxglove bridge):
    ``read(decode, buf)`` is the decoded message, or None for one it cannot read
    (malformed, stamped before 1970), dropped and counted; the first is reported
    (``report(text)``), never raised into the node."""

    def __init__(self, report):
        self.report, self.dropped = report, 0

    def __call__(self, decode, buf):
        try:
            return decode(buf)
        except ValueError as exc:
            self.dropped += 1
            if self.dropped == 1:
                self.report(f"not shown: {exc}")
            return None
