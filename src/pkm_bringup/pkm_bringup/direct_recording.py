"""The recording of a direct run (pkm_bringup.direct): the bag the graph's recorder
writes, or a study's messages kept in memory.

Three recorders with one interface (``index``, ``tap``, ``start`` once the run is
wired, ``flush``, ``close``, ``abandon``):

- :class:`Recorder`: the bag written in the run's process (one tap,
  pkm_recording.tap, a batch at a time in one compiled pass).
- :class:`RecorderProcess`: the same writer in a process of its own, as the graph's
  recorder is: the run's process hands it the tap's batches through a pipe and goes
  on while it compresses and writes (~6 % of a recorded ARCHI step). Forked once the
  run is wired, it may also do work beside the loop on each batch (``BatchWork``:
  pkm_bringup.direct_beside). Used where the run's process may fork safely (one
  thread: pkm-run); elsewhere (a Dask worker's threads) :func:`bag_recorder` gives
  the in-process one. The bag is the same bytes.
- :class:`MemoryRecorder`: no bag, the messages kept in memory
  (pkm_recording.memory: a study's run whose bag would be removed once read).
"""

from __future__ import annotations

import fcntl
import os
import pickle
import signal
import sys
import threading
from multiprocessing.connection import Pipe
from typing import Protocol

from pkm_common import topics
from pkm_common.qos import publisher_qos
from pkm_recording.bag import BagWriter
from pkm_recording.memory import MemoryRecording
from pkm_recording.recording import qos_dict
from pkm_recording.tap import MAGIC, StreamTap, split_batch
from pkm_recording.tap_records import StampCounter, record_stamp

__all__ = ["BatchWork", "MemoryRecorder", "Recorder", "RecorderProcess", "RecordingFailed", "bag_recorder", "may_fork"]

CLOSE_TIMEOUT_S = 600.0       # the writer's last batch and the bag's summary
F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)     # Linux's fcntl (Python 3.10+ names it)
PIPE_BYTES = 1 << 20


class RecordingFailed(RuntimeError):
    """The bag's writer failed (a full disk, a path it cannot write): the writer's error."""


def _summary(writer: BagWriter, stamps: StampCounter, channels: dict[str, int]) -> dict:
    """recorder_node's summary of a bag written from a tap."""
    return {"recorded": writer.counts,
            "recorded_stamps": {name: stamps.count(c) for name, c in channels.items()},
            "tapped": sorted(channels), "tap_errors": 0, "tap_batches": 0, "tap_lists": 0, "tap_forged": 0}


class _BagSide:
    """The writing half of a recorder: the bag's channels, the tap's batches written,
    the count of new stamps per channel (its summary, as recorder_node's)."""

    def __init__(self, output: str, compression: str):
        self.writer = BagWriter(output, compression=compression)
        self.channels: dict[str, int] = {}
        self.stamps = StampCounter()

    def add_topic(self, name: str, relative: str) -> None:
        if name not in self.channels:
            msgtype = topics.CATALOGUE[relative].type
            self.channels[name] = channel = self.writer.add_topic(name, msgtype,
                                                                  [qos_dict(publisher_qos(relative))])
            self.stamps.reserve(channel)

    def write(self, payload) -> None:
        table, region, count = split_batch(payload)
        written, stamps = self.writer.write_tap_records(region, count, [self.channels[name] for name, _ in table])
        self.stamps.add(written, stamps)

    def close(self) -> dict:
        self.writer.close()
        return _summary(self.writer, self.stamps, self.channels)


class Recorder:
    """The bag of a direct run written in the run's process: every message the loops
    publish, as the graph's recorder writes it, with the topic's QoS from the
    catalogue."""

    def __init__(self, output: str, compression: str):
        self.bag = _BagSide(output, compression)
        self.tap = StreamTap()

    def index(self, name: str, relative: str) -> int:
        """The tap index of a topic (``relative``: its catalogue name), its channel made."""
        self.bag.add_topic(name, relative)
        return self.tap.topic_index(name, topics.CATALOGUE[relative].type)

    def flush(self) -> None:
        payload = self.tap.take_payload()
        if payload is not None:
            self.bag.write(payload)

    def close(self) -> dict:
        """The last batch, the bag finalized; the summary recorder_node writes."""
        try:
            self.flush()
        finally:
            summary = self.bag.close()
        return summary

    def start(self, work: None = None) -> None:
        """Nothing to start: the bag is written here (no work beside the loop)."""

    def abandon(self) -> None:
        """The run was never wired: the bag closed as it is."""
        self.bag.writer.close()


def _portable(exc: BaseException) -> BaseException:
    """The writer's error as the run's process raises it: a refused bag path stays a
    ValueError (a refused configuration) and an OSError keeps its errno (a full disk:
    files.disk_full), with their messages; anything else is a RecordingFailed naming it."""
    if isinstance(exc, OSError):
        return OSError(exc.errno, f"the bag's writer: {exc.strerror or exc}", exc.filename)
    if isinstance(exc, ValueError):
        return ValueError(str(exc))
    return RecordingFailed(f"the bag's writer failed: {type(exc).__name__}: {exc}")


def _serve(batches, answers, output: str, compression: str, registered: list, work) -> None:
    """The writer process: the topics ``registered`` before it started, then from the
    run, in order, the tap's batches (their bytes) and pickled ("topic", name,
    relative) and ("close",); each batch through ``work`` (BatchWork) if any, then
    written. It answers ("ready",) once the bag is open, ("summary", the bag's, the
    work's) at the close, or ("error", the error) and ends. The end of the pipe (the
    run's process gone) closes the bag as it is."""
    bag = None
    try:
        bag = _BagSide(output, compression)
        for name, relative in registered:
            bag.add_topic(name, relative)
        answers.send(("ready",))
        while True:
            try:
                data = batches.recv_bytes()
            except EOFError:
                break
            if data[:len(MAGIC)] == MAGIC:
                if work is not None:
                    data = work.apply(data, bag.add_topic)
                bag.write(data)
                continue
            message = pickle.loads(data)
            if message[0] == "topic":
                bag.add_topic(message[1], message[2])
            else:
                summary, bag = bag.close(), None
                answers.send(("summary", (summary, None if work is None else work.summary())))
                break
    except BaseException as exc:             # noqa: BLE001 - the writer's every failure, to the run
        try:
            answers.send(("error", _portable(exc)))
        except OSError:
            pass
    finally:
        if bag is not None:
            try:
                bag.writer.close()
            except BaseException:            # noqa: BLE001 - nothing left to tell
                pass


class BatchWork(Protocol):
    """What the writer process does to each batch before it writes it
    (RecorderProcess.start): work the loop does not wait for, done beside it."""

    def apply(self, payload: bytes, add_topic) -> bytes:
        """The batch to write (``add_topic(name, relative)``: a channel for a topic the
        work adds)."""

    def summary(self) -> dict:
        """What the work did, returned by the close."""


class RecorderProcess:
    """:class:`Recorder` with the writing in a forked process of its own (module doc),
    forked by :meth:`start` once the run is wired (the topics indexed before are
    registered then). The pipe holds a batch or two at most (a send waits for the
    writer when it is full): memory stays flat however long the run. A failure of
    the writer is raised, with its error, at the start, the next batch or the close
    (:func:`_portable`)."""

    def __init__(self, output: str, compression: str):
        self.output, self.compression = output, compression
        self.tap = StreamTap()
        self.registered: list[tuple[str, str]] = []     # (name, relative) before the start
        self.pid = None
        self.closed = False
        self.work_summary = None

    def start(self, work: BatchWork | None = None) -> None:
        """Fork the writer (its copy of this process as it is now: ``work`` with it)."""
        batches, self.batches = Pipe(duplex=False)          # (reader, writer): to the writer
        self.conn, answers = Pipe(duplex=False)             # from it
        _widen(self.batches)
        for stream in (sys.stdout, sys.stderr):
            stream.flush()                   # nothing buffered written twice
        self.pid = os.fork()
        if self.pid == 0:                    # the writer: it ends with os._exit, never returns
            code = 1
            try:
                for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                    signal.signal(number, signal.SIG_IGN)   # the run's process decides when it ends (EOF)
                self.conn.close()
                self.batches.close()
                _serve(batches, answers, self.output, self.compression, self.registered, work)
                code = 0
            finally:
                os._exit(code)
        batches.close()
        answers.close()
        self._answer("ready")

    def _answer(self, kind: str):
        """The writer's next answer, which must be ``kind``; its error raised."""
        try:
            if not self.conn.poll(CLOSE_TIMEOUT_S):
                raise RecordingFailed(f"the bag's writer gave no answer in {CLOSE_TIMEOUT_S:g} s")
            message = self.conn.recv()
        except (EOFError, OSError):
            message = ("error", RecordingFailed("the bag's writer ended"))
        if message[0] == "error":
            self._reap()
            raise message[1]
        return message[1] if len(message) > 1 else None

    def _send(self, data: bytes) -> None:
        """A batch's bytes, or a pickled message (which cannot start as a batch does)."""
        if self.conn.poll():                 # the writer said something unasked: its error
            self._answer("")
        try:
            self.batches.send_bytes(data)
        except OSError:
            self._answer("")                 # its error, or that it ended
            raise RecordingFailed("the bag's writer ended") from None

    def index(self, name: str, relative: str) -> int:
        if self.pid is None:
            self.registered.append((name, relative))
        else:
            self._send(pickle.dumps(("topic", name, relative)))
        return self.tap.topic_index(name, topics.CATALOGUE[relative].type)

    def flush(self) -> None:
        payload = self.tap.take_payload()
        if payload is not None:
            self._send(payload)

    def close(self) -> dict:
        """The last batch, the bag finalized by the writer; its summary (the work's:
        ``work_summary``)."""
        try:
            self.flush()
            self._send(pickle.dumps(("close",)))
            summary, self.work_summary = self._answer("summary")
            return summary
        finally:
            self._reap()

    def abandon(self) -> None:
        """The run was never wired, or failed: the writer closes the bag as it is and ends."""
        self._reap()

    def _reap(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.pid is None:                 # never started: no bag made
            return
        self.batches.close()                 # the end of the writer's input: it closes the bag and ends
        self.conn.close()
        os.waitpid(self.pid, 0)


def _widen(connection) -> None:
    """The pipe to the writer made to hold a batch or two (1 MiB, Linux's default
    largest), so that a batch is handed over without waiting for the writer to wake;
    left as it is where the system refuses."""
    try:
        fcntl.fcntl(connection.fileno(), F_SETPIPE_SZ, PIPE_BYTES)
    except (OSError, AttributeError):
        pass


def may_fork() -> bool:
    """Whether this process may fork its bag's writer: it has one thread (a fork copies
    only the calling thread, and a lock another one held would never be released in
    the copy)."""
    return threading.active_count() == 1 and hasattr(os, "fork")


def bag_recorder(output: str, compression: str) -> Recorder | RecorderProcess:
    """The bag's writer in a process of its own where this process may fork, else in
    this process."""
    return RecorderProcess(output, compression) if may_fork() else Recorder(output, compression)


class MemoryRecorder:
    """:class:`Recorder` for a run whose messages are kept in memory instead of a bag
    (pkm_recording.memory.MemoryRecording: a study's run whose bag would be removed once
    read): every message handed to the recording as published, the same summary."""

    def __init__(self, recording: MemoryRecording):
        self.recording = recording
        self.tap = self                      # Topic.publish hands each message to tap.add_indexed

    def index(self, name: str, relative: str) -> int:
        return self.recording.add_topic(name, topics.CATALOGUE[relative].type, [qos_dict(publisher_qos(relative))])

    def add_indexed(self, index: int, data: bytes, publish_time_ns: int) -> None:
        self.recording.add(index, publish_time_ns, data)

    def flush(self) -> None:
        pass

    def close(self) -> dict:
        """recorder_node's summary: per topic the messages, and those with a new header
        stamp (StampCounter over the messages in the order written, as the bag's)."""
        connections = self.recording.connections
        stamps = StampCounter(max(len(connections), 1))
        for cid, _, raw in self.recording.written():
            stamps.add_one(cid, record_stamp(raw))
        names = [c.topic for c in connections]
        return {"recorded": {c.topic: c.msgcount for c in connections},
                "recorded_stamps": {c.topic: stamps.count(c.id) for c in connections},
                "tapped": sorted(names), "tap_errors": 0, "tap_batches": 0, "tap_lists": 0, "tap_forged": 0}

    def start(self, work: None = None) -> None:
        """Nothing to start (no work beside the loop)."""

    def abandon(self) -> None:
        pass
