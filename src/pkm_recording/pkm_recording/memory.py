"""A run's messages kept in memory instead of a bag (pure, no rclpy): for a study's run
in the direct engine whose bag would be removed as soon as its metrics were read
(``keep_runs: false``), writing the MCAP and parsing it back cost ~16 % of the run.

:class:`MemoryRecording` takes what a recorder would write (a topic, then per message
its topic, log time and serialized CDR bytes, in the order written) and gives it back
the way ``pkm_runs.report_data.RunReader`` reads a bag through rosbags' ``AnyReader``:
``connections`` (topic, msgtype, msgcount), ``messages()`` in log-time order (ties in
the order written) and ``deserialize(raw, msgtype)`` (rosbags' Jazzy typestore).
Memory grows with the run: the caller keeps it for runs of bounded length
(``MAX_SECONDS`` of simulated time).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Connection", "MAX_SECONDS", "MemoryRecording"]

# the longest run kept in memory (simulated seconds): ~7 messages a step at 1 kHz, each
# ~150 bytes and a Python record around them, ~2-3 MB a second (~300 MB at the bound)
MAX_SECONDS = 120.0


@dataclass
class Connection:
    """A topic as rosbags names it (AnyReader's Connection: the fields RunReader reads)."""

    id: int
    topic: str
    msgtype: str
    msgcount: int = 0


class MemoryRecording:
    """The messages of one run, in memory (see the module doc)."""

    def __init__(self):
        self._connections: list[Connection] = []
        self._by_topic: dict[str, Connection] = {}
        self._records: list[tuple[int, int, int, bytes]] = []   # (log_ns, order, connection id, raw)
        self._qos: list = []                                     # per connection id
        self._typestore = None

    def add_topic(self, topic: str, msgtype: str, offered_qos: list | None = None) -> int:
        """The id of ``topic`` (made on first use; its type must not change);
        ``offered_qos``: its publisher's QoS, as a bag's channel carries it (write_bag)."""
        found = self._by_topic.get(topic)
        if found is None:
            found = Connection(len(self._connections), topic, msgtype)
            self._connections.append(found)
            self._by_topic[topic] = found
            self._qos.append(offered_qos)
        elif found.msgtype != msgtype:
            raise ValueError(f"topic {topic}: recorded as {found.msgtype}, not {msgtype}")
        return found.id

    def add(self, connection_id: int, log_ns: int, raw: bytes) -> None:
        """One message of the topic ``connection_id`` (:meth:`add_topic`), logged at ``log_ns``."""
        self._connections[connection_id].msgcount += 1
        self._records.append((int(log_ns), len(self._records), connection_id, bytes(raw)))

    @property
    def connections(self) -> list[Connection]:
        return list(self._connections)

    def written(self):
        """(connection id, log time ns, raw CDR) in the order written."""
        for log_ns, _, cid, raw in self._records:
            yield cid, log_ns, raw

    def messages(self, connections=None):
        """(connection, log time ns, raw CDR) in log-time order; only ``connections``' when given."""
        wanted = None if connections is None else {c.id for c in connections}
        for log_ns, _, cid, raw in sorted(self._records):
            if wanted is None or cid in wanted:
                yield self._connections[cid], log_ns, raw

    def deserialize(self, raw: bytes, msgtype: str):
        """A message as a rosbags object (the status, estop and trajectory RunReader reads)."""
        if self._typestore is None:
            from .bag import jazzy_typestore        # (the process's: its deserializers made once)
            self._typestore = jazzy_typestore()
        return self._typestore.deserialize_cdr(raw, msgtype)

    def write_bag(self, path, compression: str = "lz4") -> None:
        """The messages as the rosbag2 MCAP bag a recorder would have written at ``path``
        (a run kept in memory that failed: its directory is kept, pkm-report and
        pkm-replay read it)."""
        from .bag import BagWriter
        writer = BagWriter(path, compression=compression)
        try:
            channels = [writer.add_topic(c.topic, c.msgtype, self._qos[c.id]) for c in self._connections]
            for cid, log_ns, raw in self.written():
                writer.write(channels[cid], log_ns, raw)
        finally:
            writer.close()

    def __len__(self) -> int:
        return len(self._records)
