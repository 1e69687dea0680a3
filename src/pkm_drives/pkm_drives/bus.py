"""Opening the drives' CAN bus (no rclpy), and bridging one between processes.

- On a real machine: python-can's ``socketcan`` interface on ``can0`` (set up with
  ``ip link set can0 up type can bitrate 1000000``), from the machine file's
  ``drives.bus``.
- In one process: python-can's ``virtual`` interface, every bus of one channel name
  seeing the others' frames.
- A simulated bus (virtual, remote) carries a frame in its transmission time at the
  bitrate (``TimedBus``), so that it carries no more than the real one.
- Between processes: ``python-can-remote`` (PyPI), a CAN-over-WebSocket bridge. The
  process that hosts the virtual drives serves its virtual channel on 127.0.0.1 at a
  port the kernel picks (``serve_bus``) and writes the URL to a file; the drive
  interface opens the ``remote`` interface on it (``open_bus`` with ``channel_file``).
  TCP on the loopback: nothing leaves the host, no multicast.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import can
import canopen

from .bus_timing import frame_bits
from .drive_config import BusSettings

__all__ = ["open_network", "serve_bus", "BusServer", "TimedBus", "SIMULATED"]

NOTIFIER_CYCLE_S = 0.05          # the notifier thread's receive timeout: how long a shutdown waits for it
SIMULATED = ("virtual", "remote")     # the interfaces of a simulated bus: TimedBus gives them a wire's time
SLEEP_AHEAD_S = 3e-4             # a sender sleeps only when the wire is busier than this (sleep's overshoot)


class _Wire:
    """One channel's wire in this process: frames go out one after the other, each
    taking its bits' time (bus_timing.frame_bits, worst-case stuffing)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.busy_until = 0.0


_WIRES: dict[str, _Wire] = {}
_WIRES_LOCK = threading.Lock()


class TimedBus(can.BusABC):
    """A python-can bus whose frames take their transmission time at ``bitrate``: each
    ``send`` waits for the wire (shared by every TimedBus of the channel in this
    process) and holds it for the frame's bits, so a simulated bus carries no more than
    a real one. Across processes each side's frames are timed by their sender (the
    master's RPDOs and SYNC, then the drives' TPDOs: a cycle's frames follow each other
    anyway)."""

    def __init__(self, inner: can.BusABC, channel: str, bitrate: int):
        self.inner, self.bitrate = inner, bitrate
        with _WIRES_LOCK:
            self.wire = _WIRES.setdefault(channel, _Wire())
        self.channel_info = f"{inner.channel_info} (timed at {bitrate} bit/s)"
        super().__init__(channel=channel)

    def send(self, msg: can.Message, timeout=None) -> None:
        with self.wire.lock:
            now = time.perf_counter()
            start = max(now, self.wire.busy_until)
            self.wire.busy_until = end = start + frame_bits(len(msg.data)) / self.bitrate
        if end - now > SLEEP_AHEAD_S:
            time.sleep(end - now)
        self.inner.send(msg, timeout)

    def _recv_internal(self, timeout):
        return self.inner.recv(timeout), False

    def shutdown(self) -> None:
        super().shutdown()
        self.inner.shutdown()


def open_network(bus: BusSettings, channel_file: str = "", timeout_s: float = 10.0,
                 timed: bool | None = None) -> canopen.Network:
    """A connected canopen.Network on ``bus``; ``channel_file``: read the channel from
    this file, waiting for it (a bridge's URL, written when it is up); ``timed``: frames
    take their transmission time (TimedBus; default: on a simulated bus). OSError naming
    the bus when it cannot be opened within ``timeout_s``."""
    timed = bus.interface in SIMULATED if timed is None else timed
    deadline = time.monotonic() + timeout_s
    channel = bus.channel
    if channel_file:
        path = Path(channel_file)
        while not (path.exists() and path.read_text().strip()):
            if time.monotonic() > deadline:
                raise OSError(f"drives bus: no channel in {channel_file} within {timeout_s:g} s")
            time.sleep(0.02)
        channel = path.read_text().strip()
    while True:
        try:
            raw = can.Bus(interface=bus.interface, channel=channel, bitrate=bus.bitrate)
            network = canopen.Network(TimedBus(raw, channel, bus.bitrate) if timed else raw)
            break
        except (can.CanError, OSError) as exc:
            if time.monotonic() > deadline:
                raise OSError(f"drives bus: cannot open {bus.interface} {channel}: {exc}") from None
            time.sleep(0.05)
    network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
    return network.connect()


class BusServer:
    """A python-can-remote server bridging ``channel`` (a virtual bus of this process)
    to other processes, on 127.0.0.1 at ``port`` (``url``)."""

    def __init__(self, channel: str, port: int = 0):
        from can_remote.server import RemoteServer       # only the hosting process needs it
        self.server = RemoteServer(host="127.0.0.1", port=port, interface="virtual", channel=channel)
        self.url = f"ws://127.0.0.1:{self.server.server_port}/"
        self.thread = threading.Thread(target=self.server.serve_forever, name="can-bridge", daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def serve_bus(channel: str, url_file: str = "") -> BusServer:
    """Serve ``channel`` to other processes; its URL written to ``url_file`` (atomically)."""
    server = BusServer(channel)
    if url_file:
        tmp = Path(url_file + ".tmp")
        tmp.write_text(server.url + "\n")
        tmp.replace(url_file)
    return server
