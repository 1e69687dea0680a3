"""A recorded run read for its report: the bag streamed as blocks of per-step columns.

Pure module (no rclpy). The bag (rosbag2 + MCAP) is read in log-time order with rosbags'
``AnyReader`` (message definitions from the bag, ``Stores.ROS2_JAZZY`` as fallback).

The per-step streams (:data:`STEP_STREAMS`: drive state and command, true pose,
reference, metrology, /clock) are deduplicated by header stamp, keeping the last
message of a stamp (the state of step 0 is republished while the graph comes up), and
joined by stamp into :class:`StepBlock` s of at most :data:`BLOCK_ROWS` rows, in stamp
order: one row per stamp, per stream a ``present`` flag, the receive time and the values
as float64 columns. A stamp is handed out once a per-step message :data:`LOOKBACK_NS`
of sim time newer has been read; a message of a stamp older than what was handed out
is dropped and counted (``StreamInfo.late``, ``late_dropped`` in metrics.json; the
streams of the graph lag each other by a few steps, but a stream stamped in another
time base than the others would show there). Memory: the look-back and one block,
whatever the length of the run. A block's messages of one stream and one layout are
decoded in one numpy view, checked against ``pkm_common.cdr``'s decoding of the first;
others one by one (``pkm_common.cdr``, rosbags' deserializer for another encoding).

* :func:`find_bag`     a run directory or bag path -> the rosbag2 directory or .mcap file
* :class:`RunReader`   ``with RunReader(bag) as r: for block in r.blocks(): ...``; ``r.info``
* :func:`load_run`     the whole run in memory (:class:`RunData`, per-topic arrays): for
  analyses and tests of short runs; the report itself streams.

Why over 600 lines: it is the one streamed reader of a run (the bag's connections,
the per-stamp assembly of every stream into blocks, their decoders, the whole-run
view built on it); its parts are private to that one job.
"""

from __future__ import annotations

import contextlib
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pkm_recording.bag import check_complete
from pkm_common import topics
from pkm_common.cdr import (CDR_LE_HEADER, JointStateDecoder, decode_joint_state, decode_multidof_trajectory,
                            decode_pose_stamped)
from pkm_kinematics.rotations import yaw_of_quaternion, yaw_of_quaternions

NS_PER_S = 1_000_000_000
DEFAULT_NAMESPACE = "/pkm"
BLOCK_ROWS = 2048                   # stamps per block handed to the analysis
LOOKBACK_NS = 2 * NS_PER_S          # sim time a stamp stays open for more messages
_CHECK_EVERY = 4096                 # messages between two looks for final stamps

# topics relative to the machine namespace (pkm_common.topics, the graph's catalogue)
STATE, COMMAND = topics.DRIVES_STATE, topics.DRIVES_COMMAND
TRUE_POSE, REFERENCE = topics.TRUE_POSE, topics.CONTROLLER_REFERENCE
STRUTS, METROLOGY_POSE = topics.METROLOGY_STRUTS, topics.METROLOGY_POSE
STATUS, DIAGNOSTICS = topics.CONTROLLER_STATUS, topics.DIAGNOSTICS
TRAJECTORY, LOAD, ESTOP = topics.TRAJECTORY, topics.LOAD, topics.ESTOP
KNOWN_SUFFIXES = (STATE, COMMAND, TRUE_POSE, REFERENCE, STRUTS, METROLOGY_POSE, STATUS,
                  DIAGNOSTICS, TRAJECTORY, LOAD, ESTOP)
CLOCK_TOPIC = topics.CLOCK

JOINT, POSE, CLOCK = "joint", "pose", "clock"
# per-step stream -> (topic suffix, or the absolute /clock; message kind)
STEP_STREAMS = {"state": (STATE, JOINT), "command": (COMMAND, JOINT), "struts": (STRUTS, JOINT),
                "true_pose": (TRUE_POSE, POSE), "reference": (REFERENCE, POSE),
                "metrology_pose": (METROLOGY_POSE, POSE), "instrument": (topics.LASER_POINT, POSE),
                "clock": (CLOCK_TOPIC, CLOCK)}
JOINT_FIELDS = ("position", "velocity", "effort")

_STAMP = struct.Struct("<iI")


class NoBagError(FileNotFoundError):
    """The given directory holds no rosbag2 recording."""


class BagReadError(ValueError):
    """The bag is there but rosbags cannot read it (a corrupt chunk, a foreign format)."""


# ------------------------------------------------------------------ records
@dataclass
class StatusRecord:
    """One DiagnosticStatus of controller/status or diagnostics."""
    stamp_ns: int
    log_ns: int
    topic: str
    name: str
    level: int
    message: str
    values: dict                    # key -> value string, as published


@dataclass
class StatusDigest:
    """What the report keeps of one status name's records, however many there are."""
    count: int = 0
    last: StatusRecord | None = None          # in bag order
    first_error: StatusRecord | None = None   # level >= 2, the earliest by (stamp, log time)
    latest_values: dict = field(default_factory=dict)   # key -> value of the last record holding it

    def add(self, rec: StatusRecord) -> None:
        self.count += 1
        self.last = rec
        self.latest_values.update(rec.values)
        if rec.level >= 2 and (self.first_error is None or (rec.stamp_ns, rec.log_ns) <
                               (self.first_error.stamp_ns, self.first_error.log_ns)):
            self.first_error = rec


@dataclass
class StreamInfo:
    """One per-step stream of the bag: its drive names and ``n`` values per array (joint
    streams; fixed by its first message, by stamp), messages ``recorded``, distinct
    stamps ``kept`` and ``late`` messages (of a stamp already handed out: dropped)."""
    key: str
    topic: str
    kind: str
    names: list = field(default_factory=list)
    n: int | None = None
    recorded: int = 0
    kept: int = 0
    late: int = 0

    @property
    def duplicates(self) -> int:
        return self.recorded - self.kept


@dataclass
class RunInfo:
    """Everything of a run that is not a per-step column: complete once the blocks
    have all been read."""
    bag_path: Path
    namespace: str
    topics: dict                    # topic -> message type
    indexed_counts: dict            # topic -> messages, from the bag's index (known at open)
    counts: dict = field(default_factory=dict)        # topic -> messages read (raw)
    stamp_counts: dict = field(default_factory=dict)  # topic -> messages with a new stamp
    streams: dict = field(default_factory=dict)       # stream key -> StreamInfo (streams in the bag)
    statuses: dict = field(default_factory=dict)      # status name -> StatusDigest
    estop: bool = False             # any estop message true
    estop_first_log_ns: int | None = None

    def topic(self, suffix: str) -> str:
        return f"{self.namespace}/{suffix}"

    def has_messages(self, key: str) -> bool:
        """The bag holds messages of the per-step stream ``key`` (by its index)."""
        return key in self.streams


# ------------------------------------------------------------------ blocks
@dataclass
class JointRows:
    """A JointState stream in a block: row i holds the message of stamp_ns[i] if
    present[i] (NaN otherwise, and where an array had another length than the names)."""
    present: np.ndarray             # (R,) bool
    log_ns: np.ndarray              # (R,) int64, receive time of the kept message
    position: np.ndarray            # (R, n)
    velocity: np.ndarray            # (R, n)
    effort: np.ndarray              # (R, n)

    def take(self, index) -> JointRows:
        return JointRows(self.present[index], self.log_ns[index], self.position[index], self.velocity[index],
                         self.effort[index])


@dataclass
class PoseRows:
    """A PoseStamped stream in a block, as :class:`JointRows`."""
    present: np.ndarray
    log_ns: np.ndarray
    position: np.ndarray            # (R, 3) m
    orientation: np.ndarray         # (R, 4) quaternion (x, y, z, w)

    def take(self, index) -> PoseRows:
        return PoseRows(self.present[index], self.log_ns[index], self.position[index], self.orientation[index])


@dataclass
class ClockRows:
    """/clock in a block: the stamp is the clock value."""
    present: np.ndarray
    log_ns: np.ndarray

    def take(self, index) -> ClockRows:
        return ClockRows(self.present[index], self.log_ns[index])


@dataclass
class StepBlock:
    """Rows of consecutive stamps (sorted, distinct), per stream of the bag its rows
    (None for a joint stream none of whose messages has been read yet: its width is
    unknown)."""
    stamp_ns: np.ndarray            # (R,) int64
    rows: dict                      # stream key -> JointRows | PoseRows | ClockRows | None

    def __len__(self) -> int:
        return len(self.stamp_ns)

    def take(self, index) -> StepBlock:
        """The rows ``index`` (a slice or an index array)."""
        return StepBlock(self.stamp_ns[index], {k: (r.take(index) if r is not None else None)
                                                for k, r in self.rows.items()})


yaw_of = yaw_of_quaternions          # rotation about z of quaternions (x, y, z, w), shape (N, 4)


def rpy_of(orientation: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (N, 3) of quaternions (x, y, z, w), shape (N, 4): R = Rz(c) Ry(b)
    Rx(a), ``pkm_kinematics.rotations.rpy_from_rotation`` on the rotation's entries."""
    x, y, z, w = orientation.T
    r00, r10, r20 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)
    r21, r22 = 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)
    return np.column_stack([np.arctan2(r21, r22), np.arctan2(-r20, np.hypot(r00, r10)), np.arctan2(r10, r00)])


# ------------------------------------------------------------------ reading
def find_bag(path) -> Path:
    """The rosbag2 directory (or lone .mcap file) of a run directory or a bag path."""
    path = Path(path)
    if path.is_file() and path.suffix == ".mcap":
        return path
    for candidate in (path, path / "bag"):
        if (candidate / "metadata.yaml").is_file():
            return candidate
    for candidate in (path / "bag", path):        # a recorder that died before metadata.yaml
        if not candidate.is_dir():
            continue
        if len(sorted(candidate.glob("*.mcap"))) == 1 or list(candidate.glob("*.mcap.truncated")):
            return candidate
    raise NoBagError(f"{path}: no rosbag2 recording (metadata.yaml + .mcap) in {path} or {path / 'bag'}")


def _infer_namespace(topics) -> str:
    found = set()
    for topic in topics:
        for suffix in KNOWN_SUFFIXES:
            if topic.endswith("/" + suffix):
                found.add(topic[: -len(suffix) - 1])
    if len(found) > 1:
        raise ValueError(f"the bag holds several machine namespaces {sorted(found)}: pass namespace=")
    return found.pop() if found else DEFAULT_NAMESPACE


def _stamp_time(t) -> int:
    return int(t.sec) * NS_PER_S + int(t.nanosec)


def _level(value) -> int:
    return int.from_bytes(value, "little") if isinstance(value, (bytes, bytearray)) else int(value)


@contextlib.contextmanager
def open_bag(bag):
    """``with open_bag(bag) as reader:`` rosbags' ``AnyReader`` of ``bag`` (a rosbag2
    directory or an .mcap file), message definitions from the bag, ``Stores.ROS2_JAZZY``
    as fallback. Raises ``pkm_recording.bag.IncompleteBagError`` for a bag its recorder did
    not finish, :class:`BagReadError` for one rosbags cannot open."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    check_complete(bag)
    reader = AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY))
    try:
        reader.open()
    except Exception as exc:                     # noqa: BLE001 - AnyReaderError and what it lets through
        raise BagReadError(f"{bag}: cannot be read: {exc}") from None
    try:
        yield reader
    finally:
        reader.close()


def read_messages(reader, bag, connections=None):
    """``reader.messages(connections)`` (connection, log time, raw CDR) in log-time
    order; what the reader raises while reading (a corrupt chunk) as :class:`BagReadError`."""
    messages = reader.messages() if connections is None else reader.messages(connections=connections)
    try:
        yield from messages                      # (the consumer's own errors do not come in here)
    except Exception as exc:                     # noqa: BLE001 - rosbags' errors and the decompressors'
        raise BagReadError(f"{bag}: cannot be read: {exc}") from None


class _Stream:
    """The pending (not yet handed out) messages of one per-step stream."""

    __slots__ = ("info", "msgtype", "pending", "decoder")

    def __init__(self, info: StreamInfo, msgtype: str):
        self.info, self.msgtype = info, msgtype
        self.pending: dict = {}     # stamp -> (log_ns, raw CDR), the last message of the stamp
        self.decoder = JointStateDecoder(info.topic) if info.kind == JOINT else None


class RunReader:
    """Streams a bag (see the module doc). ``with RunReader(path) as reader:`` opens it
    (``path``: a run directory, a rosbag2 directory or an .mcap file); ``reader.info``
    (:class:`RunInfo`) holds the topics from the start and the rest once
    :meth:`blocks` is exhausted. ``namespace``: the machine namespace (``/pkm``),
    inferred from the topic names when None. ``keep_records``: also keep every status
    record, estop and load message and the last trajectory (for :func:`load_run`).

    Raises :class:`NoBagError` (no recording), ``pkm_recording.bag.IncompleteBagError``
    (a bag its recorder did not finish: ``bag.recover`` makes it readable) or
    :class:`BagReadError` (rosbags cannot read it)."""

    def __init__(self, path, namespace: str | None = None, *, keep_records: bool = False,
                 block_rows: int = BLOCK_ROWS, lookback_ns: int = LOOKBACK_NS, source=None):
        # ``source``: the messages from elsewhere than a bag, read as AnyReader reads one
        # (pkm_recording.memory.MemoryRecording: a direct run's, kept in memory); ``path`` names it
        self.source = source
        self.bag = find_bag(path) if source is None else Path(path)
        self.namespace = namespace
        self.keep_records = keep_records
        self.block_rows, self.lookback_ns = int(block_rows), int(lookback_ns)
        self.info: RunInfo | None = None
        self.status_records: dict = {}          # keep_records: name -> [StatusRecord] (bag order)
        self.estop_records: list = []           # keep_records: (log_ns, bool)
        self.load_records: list = []            # keep_records: (stamp_ns, force (3,), torque (3,))
        self.trajectory = None                  # keep_records: the last trajectory message
        self._reader = None

    # -- opening
    def __enter__(self) -> RunReader:
        self._opened = open_bag(self.bag) if self.source is None else contextlib.nullcontext(self.source)
        self._reader = self._opened.__enter__()
        connections = self._reader.connections
        topics = {c.topic: c.msgtype for c in connections}
        indexed: dict = {}
        for c in connections:
            indexed[c.topic] = indexed.get(c.topic, 0) + int(c.msgcount)
        namespace = self.namespace if self.namespace is not None else _infer_namespace(topics)
        namespace = namespace.rstrip("/")
        if namespace and not namespace.startswith("/"):
            namespace = "/" + namespace
        self.info = RunInfo(self.bag, namespace, topics, indexed, counts=dict.fromkeys(topics, 0),
                            stamp_counts=dict.fromkeys(topics, 0))
        self._streams: dict = {}                 # topic -> _Stream
        for key, (suffix, kind) in STEP_STREAMS.items():
            topic = suffix if suffix.startswith("/") else f"{namespace}/{suffix}"
            if indexed.get(topic, 0) > 0:
                info = StreamInfo(key, topic, kind)
                self.info.streams[key] = info
                self._streams[topic] = _Stream(info, topics[topic])
        self._others = {f"{namespace}/{s}": s for s in (STATUS, DIAGNOSTICS, ESTOP, LOAD, TRAJECTORY)}
        return self

    def __exit__(self, *exc) -> None:
        if self._reader is not None:
            self._reader = None
            self._opened.__exit__(*exc)

    def deserialize(self, raw, msgtype: str):
        """A message of this bag as a rosbags object (the kept trajectory, ...), while open."""
        return self._reader.deserialize(raw, msgtype)

    # -- streaming
    def blocks(self):
        """The run's :class:`StepBlock` s in stamp order (a generator; read once)."""
        if self._reader is None:
            raise RuntimeError("RunReader.blocks(): open the reader first (with RunReader(...) as reader)")
        info, streams, others = self.info, self._streams, self._others
        counts, stamp_counts = info.counts, info.stamp_counts
        last_stamp: dict = {}
        pending_stamps: set = set()
        newest = None                   # the newest stamp of any per-step message
        done_below = None               # stamps below this have been handed out
        since_check, check_every = 0, min(_CHECK_EVERY, self.block_rows)
        routes: dict = {}               # topic -> (its stream or None, its other stream's suffix or None)
        for conn, log_ns, raw in read_messages(self._reader, self.bag):
            topic = conn.topic
            route = routes.get(topic)
            if route is None:
                route = routes[topic] = (streams.get(topic), others.get(topic))
            stream, suffix = route
            counts[topic] += 1
            # the header's stamp bytes (as (sec, nanosec): equal exactly when the 8 bytes are)
            head = _STAMP.unpack_from(raw, 4) if len(raw) >= 12 else raw[4:12]
            if head != last_stamp.get(topic):          # as recorder_node counts: a new stamp
                last_stamp[topic] = head
                stamp_counts[topic] += 1
            if stream is None:
                if suffix is not None:
                    self._other(suffix, topic, conn.msgtype, log_ns, raw)
                continue
            if len(raw) >= 12 and raw[:4] == CDR_LE_HEADER:
                stamp = head[0] * NS_PER_S + head[1]
            else:
                stamp = self._stamp(raw, stream.msgtype)
            if done_below is not None and stamp < done_below:
                stream.info.late += 1
                continue
            stream.pending[stamp] = (log_ns, raw)
            pending_stamps.add(stamp)
            if newest is None or stamp > newest:
                newest = stamp
            since_check += 1
            if since_check >= check_every:
                since_check = 0
                horizon = newest - self.lookback_ns
                final = [s for s in pending_stamps if s < horizon]
                if len(final) >= self.block_rows:
                    final.sort()
                    pending_stamps.difference_update(final)
                    done_below = horizon
                    for start in range(0, len(final), self.block_rows):
                        yield self._block(final[start:start + self.block_rows])
        for stream in streams.values():
            stream.info.recorded = counts[stream.info.topic]
        final = sorted(pending_stamps)
        pending_stamps.clear()
        for start in range(0, len(final), self.block_rows):
            yield self._block(final[start:start + self.block_rows])

    def _stamp(self, raw, msgtype: str) -> int:
        """The stamp of a message in another encoding than little-endian CDR."""
        msg = self._reader.deserialize(raw, msgtype)
        return _stamp_time(msg.clock if msgtype == "rosgraph_msgs/msg/Clock" else msg.header.stamp)

    def _other(self, suffix: str, topic: str, msgtype: str, log_ns: int, raw) -> None:
        """A message of a stream that is not per-step."""
        if suffix in (STATUS, DIAGNOSTICS):
            m = self._reader.deserialize(raw, msgtype)
            stamp = _stamp_time(m.header.stamp)
            for s in m.status:
                name = s.name.rsplit("/", 1)[-1].strip()
                rec = StatusRecord(stamp, int(log_ns), topic, name, _level(s.level), s.message,
                                   {kv.key: kv.value for kv in s.values})
                self.info.statuses.setdefault(name, StatusDigest()).add(rec)
                if self.keep_records:
                    self.status_records.setdefault(name, []).append(rec)
        elif suffix == ESTOP:
            value = bool(self._reader.deserialize(raw, msgtype).data)
            if value and not self.info.estop:
                self.info.estop, self.info.estop_first_log_ns = True, int(log_ns)
            if self.keep_records:
                self.estop_records.append((int(log_ns), value))
        elif self.keep_records and suffix == LOAD:
            m = self._reader.deserialize(raw, msgtype)
            f, t = m.wrench.force, m.wrench.torque
            self.load_records.append((_stamp_time(m.header.stamp), (f.x, f.y, f.z), (t.x, t.y, t.z)))
        elif self.keep_records and suffix == TRAJECTORY:
            self.trajectory = (raw, msgtype)       # only the last one is decoded

    # -- blocks
    def _block(self, stamps: list) -> StepBlock:
        rows = {}
        for stream in self._streams.values():
            pending = stream.pending
            entries = [pending.pop(s, None) for s in stamps]
            rows[stream.info.key] = self._rows(stream, entries)
        return StepBlock(np.array(stamps, dtype=np.int64), rows)

    def _rows(self, stream: _Stream, entries: list):
        r = len(entries)
        present = np.fromiter((e is not None for e in entries), dtype=bool, count=r)
        log_ns = np.fromiter((e[0] if e is not None else 0 for e in entries), dtype=np.int64, count=r)
        index = np.flatnonzero(present)
        kept = [entries[i][1] for i in index]
        stream.info.kept += len(kept)
        kind = stream.info.kind
        if kind == CLOCK:
            return ClockRows(present, log_ns)
        if kind == POSE:
            position, orientation = np.full((r, 3), np.nan), np.full((r, 4), np.nan)
            if kept:
                values = _pose_block(kept)
                if values is None:
                    values = np.array([self._pose(raw, stream) for raw in kept], dtype=float)
                position[index], orientation[index] = values[:, :3], values[:, 3:]
            return PoseRows(present, log_ns, position, orientation)
        arrays = None
        if kept:
            found = _joint_block(kept)
            if found is not None:
                names, fields = found
                arrays = self._fit(stream.info, names, fields, r, index)
            else:                       # message by message: several layouts, or another encoding
                for i, raw in zip(index, kept):
                    names, fields = self._joint(raw, stream)
                    one = self._fit(stream.info, names, [np.asarray(f, dtype=float).reshape(1, -1) for f in fields],
                                    1, [0])
                    if arrays is None:  # after the first _fit: the stream's n is known
                        arrays = [np.full((r, stream.info.n), np.nan) for _ in JOINT_FIELDS]
                    for arr, values in zip(arrays, one):
                        arr[i] = values[0]
        if stream.info.n is None:       # no message of the stream yet
            return None
        if arrays is None:
            arrays = [np.full((r, stream.info.n), np.nan) for _ in JOINT_FIELDS]
        return JointRows(present, log_ns, *arrays)

    @staticmethod
    def _fit(info: StreamInfo, names, fields, r: int, index) -> list:
        """The (R, n) position, velocity and effort arrays of a block from the
        ``fields`` (each (len(index), k)) of messages of ``names``: columns in the
        stream's name order, NaN where a field has not ``n`` values; the stream's first
        message fixes its names and ``n``."""
        names = list(names)
        if info.n is None:
            info.names = names
            info.n = len(names) or max(f.shape[1] for f in fields)
        elif names and not info.names and len(names) == info.n:
            info.names = names
        n = info.n
        order = None
        if names and info.names and names != info.names and sorted(names) == sorted(info.names):
            order = [names.index(name) for name in info.names]
        out = []
        for values in fields:
            arr = np.full((r, n), np.nan)
            if n and values.shape[1] == n:
                arr[index] = values if order is None else values[:, order]
            out.append(arr)
        return out

    def _pose(self, raw, stream: _Stream) -> tuple:
        try:
            d = decode_pose_stamped(raw, stream.info.topic)
            return d.position + d.orientation
        except ValueError:
            m = self._reader.deserialize(raw, stream.msgtype)
            p, q = m.pose.position, m.pose.orientation
            return (p.x, p.y, p.z, q.x, q.y, q.z, q.w)

    def _joint(self, raw, stream: _Stream) -> tuple:
        """(names, (position, velocity, effort)) of one JointState."""
        try:
            d = stream.decoder.decode(raw)
            return d.name, (d.position, d.velocity, d.effort)
        except ValueError:
            m = self._reader.deserialize(raw, stream.msgtype)
            return tuple(m.name), (tuple(m.position), tuple(m.velocity), tuple(m.effort))


# ------------------------------------------------------------------ bulk decoding
# A stream from one publisher has one layout: every message of a block has the same
# bytes but for the stamp and the doubles. Such a block is decoded in one numpy view;
# the first message, decoded by pkm_common.cdr, checks the offsets. Anything else
# (another layout within the block, another encoding) is decoded message by message.
def _body_pad(offset: int, alignment: int) -> int:
    """XCDR1 padding before a field at ``offset`` of the message (the body starts at 4)."""
    return -(offset - 4) % alignment


def _string_end(offset: int, text: str) -> int:
    offset += _body_pad(offset, 4)
    return offset + 4 + len(text.encode("utf-8")) + 1


def _doubles_at(kept: list, spans: list, first: np.ndarray) -> np.ndarray | None:
    """(M, total) doubles at ``spans`` [(offset, count)] of every message of ``kept``,
    if they all share the first one's layout (same size, same bytes outside the stamp
    and the doubles) and the first one's doubles are ``first``; else None."""
    size = len(kept[0])
    if any(len(raw) != size for raw in kept) or (spans and spans[-1][0] + 8 * spans[-1][1] > size):
        return None
    data = np.frombuffer(b"".join(kept), dtype=np.uint8).reshape(len(kept), size)
    layout = np.ones(size, bool)
    layout[4:12] = False
    for offset, count in spans:
        layout[offset:offset + 8 * count] = False
    fixed = data[:, layout]
    if not (fixed == fixed[0]).all():
        return None
    values = np.ascontiguousarray(np.concatenate([data[:, o:o + 8 * c] for o, c in spans], axis=1)
                                  if spans else np.zeros((len(kept), 0), np.uint8)).view("<f8")
    if not np.array_equal(values[0], first, equal_nan=True):
        return None
    return values.astype(float)


def _pose_block(kept: list) -> np.ndarray | None:
    """(M, 7) position and orientation of PoseStamped messages of one layout, or None."""
    try:
        first = decode_pose_stamped(kept[0])
    except ValueError:
        return None
    offset = _string_end(12, first.frame_id)
    offset += _body_pad(offset, 8)
    return _doubles_at(kept, [(offset, 7)], np.array(first.position + first.orientation, dtype=float))


def _joint_block(kept: list):
    """(names, [position, velocity, effort] each (M, k)) of JointState messages of one
    layout, or None."""
    try:
        first = decode_joint_state(kept[0])
    except ValueError:
        return None
    offset = _string_end(12, first.frame_id)
    offset += _body_pad(offset, 4) + 4
    for name in first.name:
        offset = _string_end(offset, name)
    spans, counts = [], []
    for values in (first.position, first.velocity, first.effort):
        offset += _body_pad(offset, 4) + 4
        counts.append(len(values))
        if values:
            offset += _body_pad(offset, 8)
            spans.append((offset, len(values)))
            offset += 8 * len(values)
    flat = np.array(first.position + first.velocity + first.effort, dtype=float)
    values = _doubles_at(kept, spans, flat)
    if values is None:
        return None
    bounds = np.cumsum([0] + counts)
    return first.name, [values[:, bounds[k]:bounds[k + 1]] for k in range(3)]


# ------------------------------------------------------------------ in memory
@dataclass
class JointSeries:
    """A JointState stream, deduplicated by header stamp (the last message of a stamp
    is kept), sorted by stamp. Missing fields are NaN."""
    names: list
    stamp_ns: np.ndarray            # (N,) int64
    log_ns: np.ndarray              # (N,) int64, recorder receive time of the kept message
    position: np.ndarray            # (N, n)
    velocity: np.ndarray            # (N, n)
    effort: np.ndarray              # (N, n)
    recorded: int                   # messages in the bag (before deduplication)

    @property
    def duplicates(self) -> int:
        return self.recorded - len(self.stamp_ns)


@dataclass
class PoseSeries:
    """A PoseStamped stream, deduplicated by stamp like :class:`JointSeries`."""
    stamp_ns: np.ndarray
    log_ns: np.ndarray
    position: np.ndarray            # (N, 3) m
    orientation: np.ndarray         # (N, 4) quaternion (x, y, z, w)
    recorded: int

    @property
    def duplicates(self) -> int:
        return self.recorded - len(self.stamp_ns)

    @property
    def yaw(self) -> np.ndarray:
        """Rotation about z (rad, in (-pi, pi]) of each orientation."""
        return yaw_of(self.orientation)


@dataclass
class RunData:
    """A whole run in memory (:func:`load_run`): ``steps`` (one :class:`StepBlock` of
    every stamp), per stream a series view of its rows, and the other streams' records."""
    info: RunInfo
    steps: StepBlock
    statuses: dict = field(default_factory=dict)   # status name -> [StatusRecord] (bag order)
    estop_log_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    estop: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    load_stamp_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    load_force: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    load_torque: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    trajectory_time_s: np.ndarray | None = None     # the last trajectory message's points
    trajectory_position: np.ndarray | None = None   # (P, 3)
    trajectory_yaw: np.ndarray | None = None        # (P,)

    bag_path = property(lambda self: self.info.bag_path)
    namespace = property(lambda self: self.info.namespace)
    topics = property(lambda self: self.info.topics)
    counts = property(lambda self: self.info.counts)
    stamp_counts = property(lambda self: self.info.stamp_counts)

    def topic(self, suffix: str) -> str:
        return self.info.topic(suffix)

    def _series(self, key: str):
        rows, info = self.steps.rows.get(key), self.info.streams.get(key)
        if rows is None or info is None:
            return None
        keep = rows.present
        if isinstance(rows, JointRows):
            return JointSeries(list(info.names), self.steps.stamp_ns[keep], rows.log_ns[keep], rows.position[keep],
                               rows.velocity[keep], rows.effort[keep], info.recorded)
        return PoseSeries(self.steps.stamp_ns[keep], rows.log_ns[keep], rows.position[keep],
                          rows.orientation[keep], info.recorded)

    state = property(lambda self: self._series("state"))
    command = property(lambda self: self._series("command"))
    struts = property(lambda self: self._series("struts"))
    true_pose = property(lambda self: self._series("true_pose"))
    reference = property(lambda self: self._series("reference"))
    metrology_pose = property(lambda self: self._series("metrology_pose"))

    @property
    def clock_ns(self) -> np.ndarray:
        rows = self.steps.rows.get("clock")
        return self.steps.stamp_ns[rows.present] if rows is not None else np.zeros(0, np.int64)

    @property
    def clock_log_ns(self) -> np.ndarray:
        rows = self.steps.rows.get("clock")
        return rows.log_ns[rows.present] if rows is not None else np.zeros(0, np.int64)


def _concat(blocks: list, info: RunInfo) -> StepBlock:
    """One block of all ``blocks`` (a stream missing from a block: absent rows)."""
    stamps = np.concatenate([b.stamp_ns for b in blocks]) if blocks else np.zeros(0, np.int64)
    rows = {}
    for key, stream in info.streams.items():
        parts = []
        for b in blocks:
            r = b.rows.get(key)
            if r is None:
                r = _absent(stream, len(b))
            parts.append(r)
        if not parts or (stream.kind == JOINT and stream.n is None):
            rows[key] = None
            continue
        cls = type(parts[0])
        rows[key] = cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__dataclass_fields__))
    return StepBlock(stamps, rows)


def _absent(stream: StreamInfo, r: int):
    present, log_ns = np.zeros(r, bool), np.zeros(r, np.int64)
    if stream.kind == CLOCK:
        return ClockRows(present, log_ns)
    if stream.kind == POSE:
        return PoseRows(present, log_ns, np.full((r, 3), np.nan), np.full((r, 4), np.nan))
    n = stream.n or 0
    return JointRows(present, log_ns, *(np.full((r, n), np.nan) for _ in JOINT_FIELDS))


def load_run(run_dir_or_bag, namespace: str | None = None) -> RunData:
    """Read a recorded run into memory (numpy arrays per stream: O(length of the run);
    the report streams instead, see :class:`RunReader`).

    ``run_dir_or_bag``: a run directory (holding ``bag/``), a rosbag2 directory or an
    .mcap file. ``namespace``: the machine namespace (``/pkm``); inferred from the topic
    names when None. Per-step streams are deduplicated by header stamp as the module
    doc says. Raises :class:`NoBagError` (a FileNotFoundError) if there is no recording,
    ``IncompleteBagError`` or :class:`BagReadError` if it cannot be read.
    """
    with RunReader(run_dir_or_bag, namespace, keep_records=True) as reader:
        blocks = list(reader.blocks())
        info = reader.info
        run = RunData(info, _concat(blocks, info), statuses=reader.status_records)
        if reader.estop_records:
            run.estop_log_ns = np.array([t for t, _ in reader.estop_records], dtype=np.int64)
            run.estop = np.array([v for _, v in reader.estop_records], dtype=bool)
        if reader.load_records:
            run.load_stamp_ns = np.array([s for s, _, _ in reader.load_records], dtype=np.int64)
            run.load_force = np.array([f for _, f, _ in reader.load_records], dtype=float)
            run.load_torque = np.array([t for _, _, t in reader.load_records], dtype=float)
        if reader.trajectory is not None:
            raw, msgtype = reader.trajectory
            if not _set_trajectory_fast(run, raw, msgtype):
                _set_trajectory(run, reader.deserialize(raw, msgtype))
    return run


def _set_trajectory_fast(run: RunData, raw, msgtype: str) -> bool:
    """The trajectory's points read by pkm_common.cdr (a 12,000-point program took
    rosbags' message objects ~1.5 s); False for a message it does not read (another
    encoding or type, a point without its transform): the general path then."""
    if msgtype != "trajectory_msgs/msg/MultiDOFJointTrajectory" or bytes(raw[:4]) != CDR_LE_HEADER:
        return False
    try:
        data = decode_multidof_trajectory(raw)
    except ValueError:
        return False
    if not data.joint_names:
        return False
    run.trajectory_time_s = data.time_s            # sec + 1e-9 nsec: the general path's to the last bit, or one ulp off
    run.trajectory_position = data.transform[:, 0, :3].copy()
    run.trajectory_yaw = np.array([yaw_of_quaternion(*q) for q in data.transform[:, 0, 3:].tolist()])
    return True


def _set_trajectory(run: RunData, msg) -> None:
    tfs = [p.transforms[0] if len(p.transforms) else None for p in msg.points]
    run.trajectory_time_s = np.array([_stamp_time(p.time_from_start) / 1e9 for p in msg.points])
    run.trajectory_position = np.array([(t.translation.x, t.translation.y, t.translation.z) if t else
                                        (np.nan,) * 3 for t in tfs]).reshape(-1, 3)
    run.trajectory_yaw = np.array([yaw_of_quaternion(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w)
                                   if t else np.nan for t in tfs])
