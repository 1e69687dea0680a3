"""Work a direct run does beside its loop (pkm_bringup.direct): what the bag records
but no loop reads is made by the bag's writer process (direct_recording.BatchWork),
not on the loop's path.

:class:`PoseBeside`: the Gough's DKM pose of each struts reading, where the
controller does not read the pose (sensor-space and encoder strategies). In the graph
gough_sensor solves it after it published the readings, in its own process, while
the controller computes; in the loop of a direct run it took ~10 us of a recorded
ARCHI step (~70). The writer's copy of the run's sensor (forked before the first
step: its DKM at its warm start, its counts at zero) solves each reading of the
batch in turn (GoughSensorLoop.solve_pose: the same poses, bit for bit) and its
ports put the pose, or the failure's diagnostics, into the batch right after the
reading, as the loop's publication would have. The sensor's summary then takes the
DKM's counts from here, and the log the failures' lines.
"""

from __future__ import annotations

import numpy as np

from pkm_common import topics
from pkm_common.cdr import JointStateDecoder
from pkm_recording.tap import StreamTap, read_batch

__all__ = ["MAX_LINES", "PoseBeside"]

MAX_LINES = 1000          # the failures' log lines kept (then counted): memory stays flat


class _Topic:
    """A topic the writer's copy of the sensor publishes on: into the batch."""

    def __init__(self, beside: PoseBeside, relative: str):
        self.beside, self.relative = beside, relative

    def publish(self, data: bytes) -> None:
        self.beside.add(self.relative, data)


class _Run:
    """What the run's ports ask of their run (direct._Ports), answered beside it."""

    def __init__(self, beside: PoseBeside):
        self.beside, self.log = beside, self

    def topic(self, relative: str) -> _Topic:
        return _Topic(self.beside, relative)

    def line(self, node: str, level: str, text: str) -> None:
        self.beside.line(f"[{level}] [{node}]: {text}")


class PoseBeside:
    """The DKM pose of each metrology/struts reading of a batch, solved by ``sensor``
    (the run's GoughSensorLoop, whose loop does not solve it: ``solves_pose`` False)
    with ports made by ``make_ports(run)`` (the run's own kind, direct._SensorPorts);
    ``name_of(relative)``: a topic's full name in the run."""

    def __init__(self, sensor, make_ports, name_of):
        self.sensor, self.make_ports, self.name_of = sensor, make_ports, name_of
        self.struts = name_of(topics.METROLOGY_STRUTS)
        self.decoder = JointStateDecoder("metrology/struts")
        self.tap = StreamTap()
        self.lines: list[str] = []
        self.lines_dropped = 0
        self.last_stamp_ns = -1
        self.time_ns = 0                     # the publish time of the reading being solved
        self.add_topic = None

    def apply(self, payload: bytes, add_topic) -> bytes:
        """The batch with each reading's pose (or failure) after it (BatchWork)."""
        if self.add_topic is None:                      # the first batch, in the writer: the copy's
            self.sensor.ports = self.make_ports(_Run(self))  # publications go into the batches
        self.add_topic = add_topic
        tap = self.tap
        for name, msgtype, time_ns, data in read_batch(payload):
            tap.add(name, msgtype, data, time_ns)
            if name == self.struts:
                self.time_ns = time_ns
                msg = self.decoder.decode(data)
                new_step = msg.stamp_ns != self.last_stamp_ns
                self.last_stamp_ns = msg.stamp_ns
                self.sensor.solve_pose(msg.stamp_ns, np.array(msg.position, dtype=float), new_step)
        return tap.take_payload()

    def add(self, relative: str, data: bytes) -> None:
        """A publication of the sensor's copy, after the reading it follows."""
        name = self.name_of(relative)
        self.add_topic(name, relative)                   # its channel, if the bag has none yet
        self.tap.add(name, topics.CATALOGUE[relative].type, data, self.time_ns)

    def line(self, text: str) -> None:
        if len(self.lines) < MAX_LINES:
            self.lines.append(text)
        else:
            self.lines_dropped += 1

    def summary(self) -> dict:
        """The DKM's counts, for the sensor's summary, and the failures' log lines."""
        counts = self.sensor.counts
        return {"solved": counts["solved"], "failed": counts["failed"],
                "published_pose": self.sensor.published["metrology/pose"], "lines": self.lines,
                "lines_dropped": self.lines_dropped}
