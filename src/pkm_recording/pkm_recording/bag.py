"""rosbag2-compatible MCAP recording: writer, crash recovery, counting.

Pure core module (no rclpy): ``recorder_node`` wraps it, tests drive it directly.

Layout (what ``ros2 bag record -s mcap`` of ROS 2 Jazzy produces, rosbag2 format 9)::

    <path>/                      the bag directory (must not exist, or be empty)
      <name>_0.mcap              <name> = basename of <path>
      metadata.yaml              written by close() (or recover())

The ``.mcap`` file: profile ``ros2``; one Schema per message type (encoding
``ros2msg``, data = the type's .msg definition followed, for each dependency, by a
line of 80 ``=``, ``MSG: pkg/Type`` and its definition); one Channel per topic
(message encoding ``cdr``, metadata ``offered_qos_profiles`` = the YAML string rosbag2
writes, ``topic_type_hash`` = ``RIHS01_...``); Message records hold the CDR bytes
exactly as received from a raw subscription (log time = receive time, publish time,
per-channel sequence number). Messages are grouped in chunks (zstd by default), each
followed by its message indexes. close() writes a ``rosbag2`` Metadata record with
``serialized_metadata`` (the bag info as in metadata.yaml; rosbag2's MCAP plugin takes
the format version from it when it reads the .mcap's own metadata, and without it
assumes format 8, whose QoS fields are integers, not the strings written here), then
the summary (schemas, channels, statistics, chunk indexes, metadata index, summary
offsets), the footer, and finally ``metadata.yaml``.

Kill -9 guarantee: the file is written without a user-space buffer. A chunk is built
in memory and handed to the OS in one write when it is full (``chunk_size`` bytes of
uncompressed records) or when flush() is called; flush() therefore leaves every
message written before it in complete chunks in the kernel's page cache, and a
kill -9 of the process afterwards loses only the messages of the open chunk
(``flush(fsync=True)`` also survives a power loss). A killed bag has no summary,
footer or metadata.yaml; :func:`recover` reads it linearly up to the last complete
chunk and rewrites it as a complete bag.

Chunk size trade-off: the node flushes every ~0.5 s. The graph's fast topics run at
1-2 kHz with 100-300-byte messages (sim_hw 1 ms exchange, trajectory 1 kHz), i.e.
roughly 0.5-2 MB/s, so most chunks are closed by the flush and ``chunk_size`` bounds
bursts: the loss on kill -9 is at most min(one flush period, ``chunk_size``) of data,
and the memory held is one chunk. Smaller chunks cost more per-chunk overhead (chunk
and index records, a chunk index entry in the summary, two write() calls) and
compress worse (zstd works per chunk); larger chunks lose more on a crash and hold
more memory. 1 MiB (the MCAP C++ writer used by rosbag2 defaults to 768 KiB) keeps the
overhead negligible and the worst-case loss small; a shorter flush period is the knob
for losing less.

Why over 600 lines: the writer, the recovery of a killed recorder's file and the
counting share the rosbag2 metadata and MCAP helpers written here once; the recovery
(reading, recovery, completeness) is the part to move out with them made public.
"""

from __future__ import annotations

import functools
import operator
import os
import re
import struct
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

import mcap.writer as _mcap_writer
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import make_reader
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from pkm_kinematics.errors import FieldError
from pkm_recording.mcap_writer import FastWriter
from pkm_recording.tap_records import PACK_ERRORS, PACK_OK, StampCounter, pack_tap_records
from pkm_common.cdr import stamp_ns_of
from pkm_common.files import atomic_write, durable

try:  # mcap's own version string, for the Header's library field
    from importlib.metadata import version as _dist_version
    _MCAP_VERSION = _dist_version("mcap")
except Exception:  # pragma: no cover - metadata missing in odd installs
    _MCAP_VERSION = "?"

__all__ = [
    "BagWriter",
    "IncompleteBagError",
    "Recovery",
    "check_complete",
    "jazzy_typestore",
    "qos_profile",
    "recorded_stamps",
    "qos_profiles_yaml",
    "recover",
    "recover_bag",
    "read_counts",
    "ROSBAG2_VERSION",
    "LIBRARY",
]

ROSBAG2_VERSION = 9
ROS_DISTRO = "jazzy"
STORAGE_ID = "mcap"
LIBRARY = f"pkm-controller pkm_recording.bag (mcap-python {_MCAP_VERSION})"
PROFILE = "ros2"
MCAP_MAGIC = b"\x89MCAP0\r\n"
_FOOTER_OPCODE = 0x02
_METADATA_FILE = "metadata.yaml"
_NS_MAX = 2**63 - 1
_U64_MAX = 2**64 - 1  # rosbag2 (and rosbags) write this starting_time for an empty bag

# RMW_DURATION_INFINITE as rmw (and rosbag2 Jazzy) write it: {sec: 9223372036, nsec: 854775807}
INFINITE_DURATION = {"sec": 9223372036, "nsec": 854775807}

_POLICIES = {
    "history": ("system_default", "keep_last", "keep_all", "unknown"),
    "reliability": ("system_default", "reliable", "best_effort", "unknown", "best_available"),
    "durability": ("system_default", "transient_local", "volatile", "unknown", "best_available"),
    "liveliness": ("system_default", "automatic", "manual_by_topic", "unknown", "best_available"),
}
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE, "": CompressionType.NONE}
_MSGTYPE_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*/[A-Za-z][A-Za-z0-9_]*$")


# --- QoS -------------------------------------------------------------------------------

def _duration(value, field: str) -> dict:
    if value is None:
        return dict(INFINITE_DURATION)
    if isinstance(value, dict):
        try:
            sec, nsec = int(value["sec"]), int(value["nsec"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"QoS {field}: expected {{'sec': int, 'nsec': int}}, got {value!r}") from None
        return {"sec": sec, "nsec": nsec}
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"QoS {field}: expected None (infinite), nanoseconds >= 0 or "
                         f"{{'sec', 'nsec'}}, got {value!r}")
    return {"sec": value // 1_000_000_000, "nsec": value % 1_000_000_000}


def _policy(kind: str, value) -> str:
    name = getattr(value, "name", value)  # also accepts rclpy policy enums
    if not isinstance(name, str) or name.lower() not in _POLICIES[kind]:
        raise ValueError(f"QoS {kind} {value!r}: expected one of {', '.join(_POLICIES[kind])}")
    return name.lower()


def qos_profile(reliability="reliable", durability="volatile", depth: int = 10,
                history="keep_last", deadline=None, lifespan=None, liveliness="automatic",
                liveliness_lease_duration=None, avoid_ros_namespace_conventions: bool = False) -> dict:
    """One offered QoS profile as rosbag2 Jazzy stores it (the dict behind the YAML).

    Policies are the rmw strings ('reliable'/'best_effort', 'volatile'/'transient_local',
    'keep_last'/'keep_all', 'automatic', ... any case, or rclpy policy enums); durations
    are None (infinite, what rosbag2 records for "not set"), integer nanoseconds or
    ``{'sec': s, 'nsec': ns}``. Raises ValueError on anything else. Keys come in
    rosbag2's order.
    """
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise ValueError(f"QoS depth: expected an int >= 0, got {depth!r}")
    return {
        "history": _policy("history", history),
        "depth": depth,
        "reliability": _policy("reliability", reliability),
        "durability": _policy("durability", durability),
        "deadline": _duration(deadline, "deadline"),
        "lifespan": _duration(lifespan, "lifespan"),
        "liveliness": _policy("liveliness", liveliness),
        "liveliness_lease_duration": _duration(liveliness_lease_duration, "liveliness_lease_duration"),
        "avoid_ros_namespace_conventions": bool(avoid_ros_namespace_conventions),
    }


def _as_time(value, name: str) -> int:
    try:
        return operator.index(value)  # int-like (numpy integers too), never float
    except TypeError:
        raise FieldError(name, f"expected integer nanoseconds, got {value!r}") from None


def _normalize_qos(profiles) -> list[dict]:
    if profiles is None:
        return []
    if isinstance(profiles, dict):
        profiles = [profiles]
    out = []
    for p in profiles:
        if not isinstance(p, dict):
            raise ValueError(f"offered QoS profile must be a dict (see qos_profile()), got {p!r}")
        unknown = set(p) - {"history", "depth", "reliability", "durability", "deadline", "lifespan",
                            "liveliness", "liveliness_lease_duration",
                            "avoid_ros_namespace_conventions"}
        if unknown:
            raise ValueError(f"offered QoS profile has unknown keys {sorted(unknown)}")
        out.append(qos_profile(**p))
    return out


def qos_profiles_yaml(profiles: list[dict]) -> str:
    """The ``offered_qos_profiles`` channel-metadata string, as rosbag2 Jazzy writes it.

    A YAML block sequence of maps in rosbag2's key order (history, depth, reliability,
    durability, deadline, lifespan, liveliness, liveliness_lease_duration,
    avoid_ros_namespace_conventions), policies as strings, durations as {sec, nsec};
    ``[]`` for no profiles; no trailing newline (yaml-cpp's ``YAML::Dump``).
    Profiles are normalized with :func:`qos_profile` first.
    """
    return yaml.dump(_normalize_qos(profiles), Dumper=_Rosbag2Dumper, default_flow_style=False,
                     sort_keys=False, width=10_000).rstrip("\n")


_YamlLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Rosbag2Dumper(yaml.SafeDumper):
    """Block YAML with sequences indented under their key, like yaml-cpp."""

    def increase_indent(self, flow=False, indentless=False):
        return super().increase_indent(flow, False)


# --- message definitions -----------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def jazzy_typestore():
    """rosbags' Jazzy typestore, one per process: a store generates each message type's
    (de)serializer on its first use (~10 ms a type), so a new store per run of a study
    paid that again for every run."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def _definition(typestore, topic: str, msgtype: str) -> tuple[str, str]:
    """(ros2msg schema text with dependencies, RIHS01 hash) of ``msgtype``."""
    if not isinstance(msgtype, str) or not _MSGTYPE_RE.match(msgtype) or "/msg/" not in msgtype:
        raise ValueError(f"topic {topic!r}: message type {msgtype!r} is not of the form "
                         f"'pkg/msg/Type' (e.g. 'sensor_msgs/msg/JointState')")
    if msgtype not in typestore.fielddefs:
        raise ValueError(f"topic {topic!r}: unknown message type {msgtype!r} (not in the ROS 2 "
                         f"Jazzy typestore; pass msgdef= or a typestore that knows it)")
    try:
        msgdef, _ = typestore.generate_msgdef(msgtype, ros_version=2)
        rihs01 = typestore.hash_rihs01(msgtype)
    except Exception as exc:  # a dependency missing from a custom typestore, ...
        raise ValueError(f"topic {topic!r}: cannot build the definition of {msgtype!r}: {exc}") from exc
    return msgdef, rihs01


# --- metadata ------------------------------------------------------------------------------

def _bag_info(file_name: str, topics: list[dict], start: int | None, end: int | None,
              custom_data: dict | None) -> dict:
    """rosbag2_bagfile_information (format 9), keys in rosbag2's order.

    ``topics``: dicts with name, type, qos (list of profile dicts), hash, count.
    """
    count = sum(t["count"] for t in topics)
    if start is None or count == 0:
        start, duration = _NS_MAX, 0
    else:
        duration = max(0, end - start)
    return {
        "version": ROSBAG2_VERSION,
        "storage_identifier": STORAGE_ID,
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t["name"], "type": t["type"],
                                "serialization_format": "cdr",
                                "offered_qos_profiles": t["qos"],
                                "type_description_hash": t["hash"]},
             "message_count": t["count"]}
            for t in topics],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [file_name],
        "files": [{"path": file_name,
                   "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration},
                   "message_count": count}],
        "custom_data": dict(custom_data) if custom_data else None,
        "ros_distro": ROS_DISTRO,
    }


def _dump_yaml(data) -> str:
    return yaml.dump(data, Dumper=_Rosbag2Dumper, default_flow_style=False, sort_keys=False,
                     width=10_000, allow_unicode=True)


def _write_metadata_yaml(directory: Path, info: dict) -> None:
    """metadata.yaml, atomically (temporary file, fsync, rename)."""
    text = _dump_yaml({"rosbag2_bagfile_information": info})
    atomic_write(directory / _METADATA_FILE, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _finish_mcap(writer: Writer, info: dict) -> None:
    """Close the chunk, add the 'rosbag2' metadata record, write summary and footer."""
    writer.flush()
    writer.add_metadata("rosbag2", {"serialized_metadata": _dump_yaml(info)})
    writer.finish()


class _RawFile:
    """Write-only file without a user-space buffer: every write() reaches the OS.

    The mcap Writer only calls write(), tell() and flush(); it writes whole records
    (a chunk, its message indexes, the summary), so unbuffered I/O costs a few
    syscalls per chunk, and a completed chunk is never stuck in a Python buffer.
    """

    def __init__(self, path: Path):
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0),
                           0o644)
        self._pos = 0

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        n = len(view)
        while view:
            view = view[os.write(self._fd, view):]
        self._pos += n
        return n

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        pass

    def fsync(self) -> None:
        if durable():              # (not for a bag thrown away once read: files.scratch)
            os.fsync(self._fd)

    def close(self) -> None:
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)


def _check_writer_args(chunk_size: int, compression: str) -> None:
    if compression not in _COMPRESSION:
        raise ValueError(f"compression {compression!r}: expected 'zstd', 'lz4' or 'none'")
    if compression == "zstd" and _mcap_writer.zstandard is None:
        raise ValueError("compression 'zstd' needs the 'zstandard' package (mcap's dependency)")
    if compression == "lz4" and _mcap_writer.lz4 is None:
        raise ValueError("compression 'lz4' needs the 'lz4' package (mcap's dependency)")
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise FieldError("chunk_size", f"expected a positive int (bytes), got {chunk_size!r}")


def _make_writer(stream, chunk_size: int, compression: str) -> Writer:
    _check_writer_args(chunk_size, compression)
    writer = FastWriter(stream, chunk_size=chunk_size, compression=_COMPRESSION[compression])
    writer.start(profile=PROFILE, library=LIBRARY)
    return writer


def _bag_file_name(directory: Path) -> str:
    name = directory.resolve().name or "bag"
    return f"{name}_0.mcap"


# --- writer -------------------------------------------------------------------------------

class _Topic:
    __slots__ = ("name", "type", "qos", "hash", "count", "seq")

    def __init__(self, name, msgtype, qos, rihs01):
        self.name, self.type, self.qos, self.hash = name, msgtype, qos, rihs01
        self.count = 0
        self.seq = 0

    def info(self) -> dict:
        return {"name": self.name, "type": self.type, "qos": self.qos, "hash": self.hash,
                "count": self.count}


class BagWriter:
    """Writes a rosbag2 (format 9) bag with MCAP storage, from raw CDR messages.

    ``BagWriter(path)`` creates the directory ``path`` (it must not exist, or be an
    empty directory) and ``path/<name>_0.mcap``. Register topics with
    :meth:`add_topic`, write raw CDR bytes with :meth:`write`, call :meth:`flush`
    periodically (completed chunks reach the OS: a kill -9 loses at most the open
    chunk) and :meth:`close` at the end (summary, footer, metadata.yaml). Thread-safe
    (one lock). Usable as a context manager; the bag is closed, not discarded, when the
    block raises.

    ``compression``: chunk compression, 'zstd' (default), 'lz4' or 'none' (mcap
    installs zstandard and lz4 as dependencies; rosbags and rosbag2 read all three).
    ``typestore``: rosbags typestore for message definitions (default: ROS 2 Jazzy).
    ``custom_data``: str -> str written to metadata.yaml's custom_data.
    """

    def __init__(self, path, chunk_size: int = 1 << 20, compression: str = "zstd",
                 storage_id: str = "mcap", *, typestore=None, custom_data: dict | None = None):
        if storage_id != STORAGE_ID:
            raise ValueError(f"storage_id {storage_id!r}: only 'mcap' is supported")
        if custom_data is not None and not all(isinstance(k, str) and isinstance(v, str)
                                               for k, v in custom_data.items()):
            raise ValueError("custom_data must map str to str")
        _check_writer_args(chunk_size, compression)
        self.path = Path(path)
        if self.path.exists():
            if not self.path.is_dir():
                raise ValueError(f"bag path {str(self.path)!r} exists and is not a directory")
            if any(self.path.iterdir()):
                raise ValueError(f"bag directory {str(self.path)!r} exists and is not empty; "
                                 f"not overwriting a recording")
        else:
            try:
                self.path.mkdir(mode=0o755, parents=True)
            except FileExistsError:
                raise ValueError(f"bag directory {str(self.path)!r} was just created by "
                                 f"someone else; not overwriting a recording") from None
        self.file_name = _bag_file_name(self.path)
        self.mcap_path = self.path / self.file_name
        # loaded now (~0.1 s) rather than in the first add_topic(), i.e. in a callback
        self._typestore = typestore if typestore is not None else jazzy_typestore()
        self._custom_data = dict(custom_data) if custom_data else None
        try:
            self._file = _RawFile(self.mcap_path)
        except FileExistsError:
            raise ValueError(f"{str(self.mcap_path)!r} exists: another writer on this bag") from None
        try:
            self._writer = _make_writer(self._file, chunk_size, compression)
        except BaseException:
            self._file.close()
            self.mcap_path.unlink()
            raise
        self._lock = threading.Lock()
        self._topics: dict[int, _Topic] = {}       # channel id -> topic
        self._by_name: dict[str, int] = {}         # topic name -> channel id
        self._schemas: dict[str, int] = {}         # msgtype -> schema id
        self._start: int | None = None
        self._end: int | None = None
        self._closed = False

    # -- registration

    def add_topic(self, topic: str, msgtype: str, offered_qos: list[dict] | None = None, *,
                  msgdef: str | None = None, type_hash: str | None = None) -> int:
        """Register ``topic`` of ``msgtype`` ('pkg/msg/Type'); returns its channel id.

        The type's schema (ros2msg with dependencies, from the typestore, or ``msgdef``
        for a type the typestore does not know) is written once per type; the channel
        carries ``offered_qos_profiles`` (``offered_qos``: dicts as built by
        :func:`qos_profile`, None/[] for none) and ``topic_type_hash``. Registering a
        topic again with the same type returns the same id; with another type, or an
        unknown type, it raises ValueError.
        """
        if not isinstance(topic, str) or not topic.startswith("/") or len(topic) < 2:
            raise ValueError(f"topic {topic!r}: expected a fully qualified name such as '/joint_states'")
        qos = _normalize_qos(offered_qos)
        with self._lock:
            self._check_open()
            cid = self._by_name.get(topic)
            if cid is not None:
                known = self._topics[cid].type
                if known != msgtype:
                    raise ValueError(f"topic {topic!r} already recorded as {known!r}, "
                                     f"cannot add it again as {msgtype!r}")
                return cid
            if msgdef is not None:
                if not isinstance(msgtype, str) or not _MSGTYPE_RE.match(msgtype):
                    raise ValueError(f"topic {topic!r}: message type {msgtype!r} is not 'pkg/msg/Type'")
                definition, rihs01 = msgdef, type_hash or ""
            else:
                definition, rihs01 = _definition(self._typestore, topic, msgtype)
                if type_hash:
                    rihs01 = type_hash
            schema_id = self._schemas.get(msgtype)
            if schema_id is None:
                schema_id = self._writer.register_schema(msgtype, "ros2msg", definition.encode())
                self._schemas[msgtype] = schema_id
            metadata = {"offered_qos_profiles": qos_profiles_yaml(qos)}
            if rihs01:
                metadata["topic_type_hash"] = rihs01
            cid = self._writer.register_channel(topic, "cdr", schema_id, metadata)
            self._topics[cid] = _Topic(topic, msgtype, qos, rihs01)
            self._by_name[topic] = cid
            return cid

    # -- data

    def write(self, channel_id: int, log_time_ns: int, data: bytes, publish_time_ns: int | None = None) -> None:
        """Append one message: raw CDR ``data`` (bytes-like) on ``channel_id``.

        ``log_time_ns``: receive time (ns since the epoch, rosbag2's recv_timestamp);
        ``publish_time_ns`` defaults to it. Each channel numbers its messages 1, 2, ...
        (MCAP sequence). Unknown channel, a time that is not an integer in [0, 2**64),
        data that is not bytes-like, or a closed bag: ValueError (checked before anything
        is written, so a rejected message never corrupts the chunk).
        """
        if type(log_time_ns) is not int:
            log_time_ns = _as_time(log_time_ns, "log_time_ns")
        if publish_time_ns is None:
            publish_time_ns = log_time_ns
        elif type(publish_time_ns) is not int:
            publish_time_ns = _as_time(publish_time_ns, "publish_time_ns")
        if not (0 <= log_time_ns <= _U64_MAX and 0 <= publish_time_ns <= _U64_MAX):
            raise ValueError(f"timestamps out of range [0, 2**64): {log_time_ns}, {publish_time_ns}")
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise ValueError(f"data must be bytes-like (raw CDR), got {type(data).__name__}")
        with self._lock:
            t = self._topics.get(channel_id)
            if t is None or self._closed:
                self._check_open()
                raise ValueError(f"write to unknown channel id {channel_id!r} "
                                 f"(known: {sorted(self._topics)}); call add_topic() first")
            t.seq = (t.seq + 1) & 0xFFFFFFFF
            self._writer.add_message(channel_id, log_time_ns, data, publish_time_ns, t.seq)
            t.count += 1
            if self._start is None:
                self._start = self._end = log_time_ns
            elif log_time_ns > self._end:
                self._end = log_time_ns
            elif log_time_ns < self._start:
                self._start = log_time_ns

    def write_tap_records(self, region, count: int, channel_of) -> tuple[np.ndarray, np.ndarray]:
        """Append the ``count`` records of a recording-tap batch's records region
        (pkm_recording.tap.split_batch) in one compiled pass (tap_records.pack_tap_records):
        a record of the tap's topic index i on channel ``channel_of[i]`` (-1: not
        recorded), log and publish time its publish time, numbered per channel like
        :meth:`write`. Returns (channel ids, header stamps) of the records written, in
        order. A malformed region, a negative time, an unknown channel or a closed bag:
        ValueError, and nothing of the batch is written."""
        with self._lock:
            self._check_open()
            topics = self._topics
            used = [topics.get(c) if c >= 0 else None for c in channel_of]     # per topic index
            sequence = np.zeros(max(channel_of, default=0) + 1, np.int64)
            for channel_id, t in zip(channel_of, used):
                if channel_id >= 0 and t is None:
                    raise ValueError(f"write to unknown channel id {channel_id!r} "
                                     f"(known: {sorted(topics)}); call add_topic() first")
                if t is not None:
                    sequence[channel_id] = t.seq
            out, channels, times, ends, stamps, per_topic, code, record = pack_tap_records(
                np.frombuffer(bytearray(region), np.uint8), count, np.array(channel_of, dtype=np.int64),
                sequence)
            if code != PACK_OK:
                raise ValueError(f"tap records: {PACK_ERRORS[code].format(k=record)} ({count} records, "
                                 f"{len(region)} bytes)")
            if len(channels):
                span = self._writer.add_packed(out, channels, times, ends)
                for channel_id, t, written in zip(channel_of, used, per_topic.tolist()):
                    if t is not None:
                        t.seq, t.count = int(sequence[channel_id]), t.count + written
                self._start = span[0] if self._start is None else min(self._start, span[0])
                self._end = span[1] if self._end is None else max(self._end, span[1])
            return channels, stamps

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic (registered topics with none: 0)."""
        with self._lock:
            return {t.name: t.count for t in self._topics.values()}

    @property
    def message_count(self) -> int:
        """Messages written so far, all topics."""
        with self._lock:
            return sum(t.count for t in self._topics.values())

    @property
    def closed(self) -> bool:
        """True once close() has run."""
        return self._closed

    def flush(self, fsync: bool = False) -> None:
        """Close the open chunk (if it holds messages) and hand it to the OS.

        Afterwards a kill -9 loses nothing written so far; ``fsync=True`` also forces
        the data to disk (power loss). No-op on a closed bag.
        """
        with self._lock:
            if self._closed:
                return
            self._writer.flush()
            if fsync:
                self._file.fsync()

    def close(self) -> None:
        """Finish the bag: last chunk, 'rosbag2' metadata record, summary, footer,
        then metadata.yaml. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                info = _bag_info(self.file_name, [t.info() for t in self._topics.values()],
                                 self._start, self._end, self._custom_data)
                _finish_mcap(self._writer, info)
                self._file.fsync()
            finally:
                self._file.close()
            _write_metadata_yaml(self.path, info)

    def _check_open(self):
        if self._closed:
            raise ValueError(f"bag {str(self.path)!r} is closed")

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"<BagWriter {str(self.path)!r} {state}, {len(self._topics)} topics>"


# --- reading, recovery ---------------------------------------------------------------------

class _Limited:
    """Read-only view of the first ``limit`` bytes of a binary file."""

    def __init__(self, fh, limit: int):
        self._fh, self._left = fh, limit

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0 or n > self._left:
            n = self._left
        data = self._fh.read(n)
        self._left -= len(data)
        return data


def _valid_prefix(fh, size: int) -> tuple[int, bool]:
    """(end of the last complete top-level record, file has a footer + closing magic)."""
    pos = len(MCAP_MAGIC)
    while pos + 9 <= size:
        fh.seek(pos)
        opcode, length = struct.unpack("<BQ", fh.read(9))
        if opcode == 0 or 0x10 <= opcode < 0x80:  # zeroed / garbage tail
            break
        end = pos + 9 + length
        if end > size:  # record cut by the kill
            break
        pos = end
        if opcode == _FOOTER_OPCODE:
            fh.seek(pos)
            return pos, fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    return pos, False


def _is_complete(path: Path) -> bool:
    """Quick check: footer record and closing magic at the end of the file."""
    size = path.stat().st_size
    if size < 8 + 9 + 20 + 8:
        return False
    with open(path, "rb") as fh:
        fh.seek(size - 37)
        tail = fh.read(37)
    return tail[:9] == b"\x02\x14" + b"\x00" * 7 and tail[-8:] == MCAP_MAGIC


def _scan(path: Path):
    """Records of an MCAP file in file order, tolerating a truncated or corrupt tail.

    Yields (Schema | Channel | Message | Metadata) records (chunks are opened, with
    their CRC checked; a chunk that does not read back whole is dropped with
    everything after it). Returns (via StopIteration.value) whether the file was
    read to its footer.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            cut = next((k for k, (a, b) in enumerate(zip(head, MCAP_MAGIC)) if a != b), len(head))
            if not head[cut:].strip(b"\x00"):
                return False  # killed while writing the magic (zero-filled tail): empty
            raise ValueError(f"{str(path)!r} is not an MCAP file (bad magic)")
        end, complete = _valid_prefix(fh, size)
        fh.seek(0)
        reader = StreamReader(_Limited(fh, end), skip_magic=False, validate_crcs=True,
                              record_size_limit=None)
        it = iter(reader.records)
        while True:
            try:
                record = next(it)
            except (StopIteration, EndOfFile):
                return complete
            except (McapError, ValueError, struct.error, EOFError) + _decompress_errors():
                return False  # corrupt chunk: stop before it
            if isinstance(record, (Schema, Channel, Message, Metadata)):
                yield record
            elif isinstance(record, Footer):
                return complete


@functools.lru_cache(maxsize=1)
def _decompress_errors() -> tuple:
    errors = []
    zstandard = _mcap_writer.zstandard
    if zstandard is not None and hasattr(zstandard, "ZstdError"):
        errors.append(zstandard.ZstdError)
    if _mcap_writer.lz4 is not None:
        errors.append(RuntimeError)  # lz4 raises RuntimeError on bad frames
    return tuple(errors)


def _mcap_files(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise ValueError(f"{str(path)!r} is neither a bag directory nor an .mcap file")
    meta = path / _METADATA_FILE
    if meta.exists():
        info = yaml.load(meta.read_text(encoding="utf-8"), Loader=_YamlLoader)["rosbag2_bagfile_information"]
        return [path / Path(p).name for p in info["relative_file_paths"]]
    return sorted(path.glob("*.mcap"))


def read_counts(path) -> dict[str, int]:
    """Per-topic message counts of a bag directory or .mcap file, read linearly.

    Reads every readable record (decompressing the chunks) with mcap's StreamReader,
    so it works on a complete bag and on one whose writer was killed (the truncated
    tail is ignored). Topics whose channel is known but has no messages count 0.
    """
    counts: dict[str, int] = {}
    for file in _mcap_files(Path(path)):
        topics: dict[int, str] = {}
        for record in _scan(file):
            if isinstance(record, Message):
                name = topics.get(record.channel_id)
                if name is not None:
                    counts[name] += 1
            elif isinstance(record, Channel):
                topics[record.id] = record.topic
                counts.setdefault(record.topic, 0)
    return counts


def _parse_qos_string(text: str) -> list[dict]:
    try:
        profiles = yaml.load(text, Loader=_YamlLoader) if text else []
        return _normalize_qos(profiles if isinstance(profiles, list) else [])
    except (yaml.YAMLError, ValueError, TypeError):
        return []


def recover(path, compression: str = "zstd", chunk_size: int = 1 << 20) -> dict[str, int]:
    """Make a bag whose writer was killed readable again; returns per-topic counts.

    A killed writer leaves ``<name>_0.mcap`` without summary and footer, and no
    metadata.yaml. The file is read linearly up to its last complete chunk, renamed to
    ``<name>_0.mcap.truncated`` (kept, never deleted), and rewritten as a complete MCAP
    (same schemas, channels, messages with their times and sequence numbers, plus the
    'rosbag2' metadata record); metadata.yaml is then written. A complete bag is left
    as it is (metadata.yaml is only written if missing), so recover() is idempotent and
    can be re-run after being interrupted. Only for a bag whose writer is dead: it
    renames the file under a live writer.
    """
    directory = Path(path)
    if not directory.is_dir():
        raise ValueError(f"{str(directory)!r} is not a bag directory")
    files = sorted(directory.glob("*.mcap"))
    truncated_files = sorted(directory.glob("*.mcap.truncated"))
    if not files and not truncated_files:
        raise ValueError(f"{str(directory)!r} holds no .mcap file")
    if len(files) > 1:
        raise ValueError(f"{str(directory)!r} holds several .mcap files; recover() handles one")
    target = files[0] if files else truncated_files[0].with_suffix("")
    backup = target.with_name(target.name + ".truncated")

    if target.exists() and _is_complete(target):
        source = None
    elif backup.exists():
        source = backup           # an earlier recover() was interrupted: start again
        if target.exists():
            target.unlink()
    else:
        os.replace(target, backup)
        source = backup

    if source is None:
        if not (directory / _METADATA_FILE).exists():
            info = _info_from_mcap(target)
            _write_metadata_yaml(directory, info)
        return read_counts(target)

    tmp = target.with_name(target.name + ".tmp")
    if tmp.exists():
        tmp.unlink()
    raw = _RawFile(tmp)
    try:
        writer = _make_writer(raw, chunk_size, compression)
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        schema_names: dict[int, str] = {}
        topics: dict[int, dict] = {}
        start = end = None
        for record in _scan(source):
            if isinstance(record, Schema):
                if record.id not in schema_ids:
                    schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
                    schema_names[record.id] = record.name
            elif isinstance(record, Channel):
                if record.id not in channel_ids and (record.schema_id in schema_ids or record.schema_id == 0):
                    new_id = writer.register_channel(record.topic, record.message_encoding,
                                                     schema_ids.get(record.schema_id, 0),
                                                     dict(record.metadata))
                    channel_ids[record.id] = new_id
                    topics[new_id] = _topic_entry(record, schema_names)
            elif isinstance(record, Message):
                new_id = channel_ids.get(record.channel_id)
                if new_id is None:
                    continue  # its channel was lost: cannot be decoded
                writer.add_message(new_id, record.log_time, record.data, record.publish_time,
                                   record.sequence)
                topics[new_id]["count"] += 1
                start, end = _widen(start, end, record.log_time)
            elif isinstance(record, Metadata) and record.name != "rosbag2":
                writer.add_metadata(record.name, dict(record.metadata))
        info = _bag_info(target.name, list(topics.values()), start, end, None)
        _finish_mcap(writer, info)
        raw.fsync()
    finally:
        raw.close()
    os.replace(tmp, target)
    _write_metadata_yaml(directory, info)
    return {t["name"]: t["count"] for t in topics.values()}


def _topic_entry(channel: Channel, schema_names: dict) -> dict:
    """A bag-info topic (count 0) from an MCAP channel record of a rosbag2 file."""
    return {"name": channel.topic, "type": schema_names.get(channel.schema_id, ""),
            "qos": _parse_qos_string(channel.metadata.get("offered_qos_profiles", "")),
            "hash": channel.metadata.get("topic_type_hash", ""), "count": 0}


def _widen(start, end, t: int) -> tuple[int, int]:
    """(start, end) extended to include t (None, None: nothing yet)."""
    return (t, t) if start is None else (min(start, t), max(end, t))


def _info_from_mcap(file: Path) -> dict:
    """bag info of a complete MCAP file (for a metadata.yaml that is missing)."""
    schemas: dict[int, str] = {}
    topics: dict[int, dict] = {}
    start = end = None
    for record in _scan(file):
        if isinstance(record, Schema):
            schemas[record.id] = record.name
        elif isinstance(record, Channel):
            topics.setdefault(record.id, _topic_entry(record, schemas))
        elif isinstance(record, Message) and record.channel_id in topics:
            topics[record.channel_id]["count"] += 1
            start, end = _widen(start, end, record.log_time)
    return _bag_info(file.name, list(topics.values()), start, end, None)


# --- completeness -----------------------------------------------------------------------------

class IncompleteBagError(ValueError):
    """A bag its writer did not finish: an .mcap file without its footer (the writer was
    killed, the disk filled up, the file was cut in a copy) or a directory without
    metadata.yaml. :func:`recover` makes it readable up to its last complete chunk."""


def check_complete(path) -> None:
    """Raise :class:`IncompleteBagError` unless ``path`` (a bag directory or an .mcap
    file) is a finished recording: a directory has its metadata.yaml and every .mcap
    file it lists exists and ends with a footer and the closing magic (the check reads
    the last 37 bytes of each file, not the data)."""
    path = Path(path)
    if path.is_file():
        files = [path]
    elif not path.is_dir():
        raise ValueError(f"{str(path)!r} is neither a bag directory nor an .mcap file")
    elif not (path / _METADATA_FILE).is_file():
        raise IncompleteBagError(f"{path}: no {_METADATA_FILE} (the recording was not closed)")
    else:
        files = _mcap_files(path)
    for file in files:
        if not file.is_file():
            raise IncompleteBagError(f"{path}: {file.name} is missing (an interrupted recovery?)")
        if not _is_complete(file):
            raise IncompleteBagError(f"{path}: {file.name} ends without an MCAP footer "
                                     f"({file.stat().st_size} bytes: the recording was cut)")


@dataclass(frozen=True)
class Recovery:
    """What :func:`recover_bag` did. ``counts``: the messages per topic in the bag now;
    ``listed``: the per-topic counts of the metadata.yaml found beside a cut .mcap (None:
    there was none, as after a kill -9, or the .mcap was complete); ``dropped_bytes``:
    the bytes after the last complete record of the cut file (an unfinished chunk: its
    messages are lost); ``rewritten``: the .mcap was rewritten (it was cut);
    ``metadata_rebuilt``: metadata.yaml was missing and has been written."""
    counts: dict
    listed: dict | None
    dropped_bytes: int
    rewritten: bool
    metadata_rebuilt: bool

    @property
    def lost(self) -> int | None:
        """Messages lost: listed - recovered (None when nothing listed them)."""
        if self.listed is None:
            return None
        return max(0, sum(self.listed.values()) - sum(self.counts.values()))

    def describe(self) -> str:
        """What was kept and lost, in one line."""
        kept = f"{sum(self.counts.values())} messages on {len(self.counts)} topics"
        if not self.rewritten:
            if self.metadata_rebuilt:
                return f"metadata.yaml rebuilt from the complete .mcap ({kept}, nothing lost)"
            return f"complete bag, nothing to recover ({kept})"
        if self.lost is not None:
            lost = f"{self.lost} of the {sum(self.listed.values())} messages its metadata.yaml listed are lost"
        else:
            lost = "the messages of the unfinished chunk are lost (nothing recorded how many)"
        return f"recovered {kept}; {lost}; {self.dropped_bytes} bytes dropped after the last complete record"


def recorded_stamps(path) -> dict[str, int]:
    """The new header stamps per topic of a bag directory's messages, in log-time order,
    as the recorder counts them (recorder_node's ``recorded_stamps``): what a recovered
    bag of a killed recorder holds, said where its summary could not be written. A
    message without a header counts at each change of its first bytes' reading."""
    counter, ids = StampCounter(), {}
    for file in sorted(Path(path).glob("*.mcap")):
        with open(file, "rb") as fh:
            for _, channel, message in make_reader(fh).iter_messages(log_time_order=True):
                if channel.topic not in ids:
                    ids[channel.topic] = len(ids)
                    counter.reserve(ids[channel.topic])
                counter.add_one(ids[channel.topic], stamp_ns_of(message.data) if len(message.data) >= 12 else -1)
    return {topic: counter.count(i) for topic, i in ids.items()}


def recover_bag(path) -> Recovery:
    """:func:`recover` of a bag directory (or of the directory of an .mcap file), with
    what it kept and lost (:class:`Recovery`). Only for a bag whose writer is dead."""
    directory = Path(path)
    if directory.is_file():
        directory = directory.parent
    files = sorted(directory.glob("*.mcap")) if directory.is_dir() else []
    cut, dropped = not files, 0            # no .mcap: only the .truncated of an interrupted recover()
    for file in files:
        if not _is_complete(file):
            cut = True
            size = file.stat().st_size
            with open(file, "rb") as fh:
                end = _valid_prefix(fh, size)[0] if fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC else 0
            dropped += max(0, size - end)
    meta = directory / _METADATA_FILE
    listed = None
    if cut and meta.is_file():
        try:
            info = yaml.load(meta.read_text(encoding="utf-8"), Loader=_YamlLoader)["rosbag2_bagfile_information"]
            listed = {t["topic_metadata"]["name"]: int(t["message_count"])
                      for t in info["topics_with_message_count"]}
        except (yaml.YAMLError, KeyError, TypeError, ValueError):
            listed = None
    metadata_rebuilt = not meta.is_file()
    counts = recover(directory)
    return Recovery(counts, listed, dropped, cut, metadata_rebuilt)
