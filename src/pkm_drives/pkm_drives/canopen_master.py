"""The CANopen master of a machine's CiA 402 drives (no rclpy): ``canopen`` does the
protocol (NMT, SDO, PDO, SYNC, EMCY, heartbeats), this module the sequence.

- ``boot``: every drive answers an SDO (device type: a CiA 402 drive), is configured
  by SDO (heartbeat 0x1017, quick stop option 0x605A, torque limit 0x6072, mode 0x6060
  = cyclic synchronous torque, the PDO mapping of ``RPDO_MAP``/``TPDO_MAPS``: TPDOs
  sent at each SYNC, RPDOs acting at the SYNC after them (``rpdo: synchronous``, the
  standard's cyclic synchronous use: every drive applies its target at the same
  instant, one cycle after the master sent it) or as they come (``on_arrival``: no
  cycle of delay, the drives a little apart in time)), then NMT start.
- ``enable``: the controlwords of cia402.MasterSequencer, one SYNC per cycle, until
  every drive is in "operation enabled".
- ``cycle(forces)``: one exchange: each drive's RPDO (controlword, target torque), a
  SYNC, then the TPDOs (statusword, position, torque actual; velocity) of every
  drive, as a ``Reading`` in SI units (drive_config.AxisScaling).
- ``check(reading)``: the supervision, each finding a ``DriveTrip`` with its cause
  (pkm_common.causes.TripCause), the drive named with its node ID and error code: an
  EMCY or a fault in the statusword (drive_fault), a drive that left operation enabled
  (drive_disabled), a TPDO that did not come for the SYNC (pdo_missed), a heartbeat
  silent for ``heartbeat_factor`` of its period (heartbeat_lost).
- ``quick_stop``: the controlword "quick stop" to every drive at once by SDO (a drive
  acts on it as it comes, not at the next SYNC), and in every RPDO after it.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import canopen

from pkm_common.causes import TripCause
from pkm_common.watchdog import SilenceWatchdog
from pkm_kinematics.errors import FieldError

from .cia402 import (CONTROLWORD, CW, Command, HomingStatus, MasterSequencer, Mode, QuickStopOption, State,
                     decode_state, error_text, homing_status)
from .drive_config import DriveSettings

__all__ = ["RPDO_MAP", "TPDO_MAPS", "REQUIRED_OBJECTS", "check_dictionary", "pdo_bytes", "DriveTrip", "Reading",
           "CanopenMaster", "DriveStartError"]

RPDO_MAP = (0x6040, 0x6071)                        # controlword, target torque
TPDO_MAPS = ((0x6041, 0x6064, 0x6077), (0x606C,))  # statusword, position, torque actual; velocity
SYNCHRONOUS = 1                                    # transmission type: act on / send at every SYNC
ON_ARRIVAL = 255                                   # an RPDO acts as it comes (asynchronous, CiA 301)
# what the master reads or writes by SDO, besides the PDOs' objects
REQUIRED_OBJECTS = {0x1000: "device type", 0x1017: "producer heartbeat time", 0x603F: "error code",
                    0x605A: "quick stop option code", 0x6060: "modes of operation", 0x6072: "max torque",
                    0x1400: "RPDO1 communication parameter", 0x1600: "RPDO1 mapping parameter",
                    0x1800: "TPDO1 communication parameter", 0x1A00: "TPDO1 mapping parameter",
                    0x1801: "TPDO2 communication parameter", 0x1A01: "TPDO2 mapping parameter"}
OBJECT_NAMES = {0x6040: "controlword", 0x6041: "statusword", 0x6064: "position actual value",
                0x606C: "velocity actual value", 0x6071: "target torque", 0x6077: "torque actual value"}
PROFILE_402 = 402
NMT_OPERATIONAL = 5                                # the state in a heartbeat (CiA 301)
CW_HOMING_START = int(CW.MODE_SPECIFIC_4)          # controlword bit 4 in homing mode: start (rising edge)


def check_dictionary(od: canopen.ObjectDictionary, source: str) -> None:
    """FieldError ``drives.eds`` when the object dictionary (an EDS) lacks an object
    the master maps in a PDO or writes, or one of them cannot be mapped."""
    for index in RPDO_MAP + tuple(i for m in TPDO_MAPS for i in m):
        if index not in od:
            raise FieldError("drives.eds", f"{source} lacks 0x{index:04X} {OBJECT_NAMES[index]}, which the drive "
                             f"interface maps in a PDO")
        if not od[index].pdo_mappable:
            raise FieldError("drives.eds", f"{source}: 0x{index:04X} {OBJECT_NAMES[index]} is not PDO-mappable")
    for index, name in REQUIRED_OBJECTS.items():
        if index not in od:
            raise FieldError("drives.eds", f"{source} lacks 0x{index:04X} {name}")


def pdo_bytes(od: canopen.ObjectDictionary) -> tuple[list[int], list[int]]:
    """(RPDO, TPDO) data bytes of one drive with this mapping (bus_timing.cycle_load)."""
    size = lambda indices: sum(len(od[i]) for i in indices) // 8      # noqa: E731 (len: bits)
    return [size(RPDO_MAP)], [size(m) for m in TPDO_MAPS]


@dataclass(frozen=True)
class DriveTrip:
    """Why the drives stop: ``cause``, the drive (index, name, node ID), its error code
    (0: none) and what was seen."""

    cause: TripCause
    drive: int
    name: str
    node_id: int
    code: int = 0
    detail: str = ""

    def text(self) -> str:
        code = f": {error_text(self.code)}" if self.code else ""
        return f"drive {self.name} (node {self.node_id}) {self.detail}{code}"


@dataclass
class Reading:
    """The drives' TPDOs of one SYNC, in SI units; ``missed``: drives whose TPDOs did
    not all come (their values are the last ones received)."""

    positions: list[float]
    velocities: list[float]
    forces: list[float]
    statuswords: list[int]
    states: list[State | None]
    limited: list[bool]
    missed: list[int]


class DriveStartError(RuntimeError):
    """The drives could not be booted or enabled (which one, in what state)."""


class CanopenMaster:
    """The master of ``settings``'s drives on ``network`` (a connected canopen.Network)."""

    def __init__(self, network: canopen.Network, settings: DriveSettings, eds: str | Path,
                 pdo_timeout_s: float = 0.5, heartbeat_factor: float = 3.0, sdo_timeout_s: float = 1.0):
        self.network, self.settings = network, settings
        self.pdo_timeout_s, self.heartbeat_factor = pdo_timeout_s, heartbeat_factor
        self.nodes = []
        for k, node_id in enumerate(settings.node_ids):
            od = canopen.import_od(str(eds), node_id)
            check_dictionary(od, Path(eds).name)
            node = canopen.RemoteNode(node_id, od)
            node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
            network.add_node(node)
            self.nodes.append(node)
        n = settings.n
        self.sequencers = [MasterSequencer() for _ in range(n)]
        self.controlwords = [CONTROLWORD[Command.DISABLE_VOLTAGE]] * n
        self.cond = threading.Condition()
        self.values = [dict.fromkeys((i for m in TPDO_MAPS for i in m), 0) for _ in range(n)]
        self.arrived = [[False] * len(TPDO_MAPS) for _ in range(n)]
        self.emcy: list[int | None] = [None] * n             # the first EMCY code of each drive since boot
        self.heartbeats = [SilenceWatchdog(own_stall_s=0.3) for _ in range(n)]
        self.nmt_states = [None] * n                         # from the heartbeats
        self.stopping = False
        self.syncs = 0
        self.lost: set[int] = set()                           # drives that missed a TPDO
        self.homed = not settings.homing_methods              # absolute encoders need no homing
        for k, node in enumerate(self.nodes):
            node.emcy.add_callback(lambda error, k=k: self._on_emcy(k, error))
            network.subscribe(0x700 + node.id, lambda can_id, data, ts, k=k: self._on_heartbeat(k, data))

    # ------------------------------------------------------------ callbacks (notifier thread)
    def _on_tpdo(self, k: int, j: int, pdo_map) -> None:
        with self.cond:
            for var in pdo_map:
                self.values[k][var.index] = var.raw
            self.arrived[k][j] = True
            self.cond.notify_all()

    def _on_emcy(self, k: int, error) -> None:
        if error.code and self.emcy[k] is None:
            self.emcy[k] = error.code

    def _on_heartbeat(self, k: int, data: bytes) -> None:
        self.heartbeats[k].feed(time.monotonic())
        self.nmt_states[k] = data[0] & 0x7F

    # ----------------------------------------------------------------- start-up
    def boot(self) -> None:
        """Every drive found, checked and configured by SDO, then NMT start (the module
        docstring); DriveStartError naming a drive that does not answer or is no CiA 402
        drive."""
        s = self.settings
        self.network.nmt.state = "PRE-OPERATIONAL"          # broadcast: SDO allowed, PDOs off
        for k, node in enumerate(self.nodes):
            who = f"drive {s.names[k]} (node {s.node_ids[k]})"
            try:
                device = node.sdo[0x1000].raw
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
                raise DriveStartError(f"{who} does not answer (SDO 0x1000: {exc}): is it on the bus "
                                      f"({s.bus.interface} {s.bus.channel}) with this node ID?") from None
            if device & 0xFFFF != PROFILE_402:
                raise DriveStartError(f"{who}: device type 0x{device:08X} is not a CiA 402 drive")
            self._configure(node, k)
        self.nmt_states = [None] * s.n
        self.network.nmt.state = "OPERATIONAL"
        # each drive's heartbeat says it is operational: its heartbeat works, and the
        # states seen from now on are not older than the start
        deadline = time.monotonic() + 3.0 * s.heartbeat_s + 1.0
        while any(st != NMT_OPERATIONAL for st in self.nmt_states) and time.monotonic() < deadline:
            time.sleep(0.005)
        late = [f"{s.names[k]} (node {s.node_ids[k]}): {'no heartbeat' if st is None else f'NMT state {st}'}"
                for k, st in enumerate(self.nmt_states) if st != NMT_OPERATIONAL]
        if late:
            raise DriveStartError(f"drives not operational after NMT start: {', '.join(late)}")

    def _configure(self, node, k: int) -> None:
        s = self.settings
        rpdo_type = SYNCHRONOUS if s.rpdo_synchronous else ON_ARRIVAL
        node.sdo[0x1017].raw = round(s.heartbeat_s * 1000.0)
        node.sdo[0x605A].raw = int(QuickStopOption.QUICK_STOP_RAMP_THEN_DISABLED)
        node.sdo[0x6072].raw = s.scaling[k].max_per_mille
        node.sdo[0x6060].raw = int(Mode.CYCLIC_SYNC_TORQUE)
        node.rpdo.read()
        node.tpdo.read()
        for maps, layout in ((node.rpdo, (RPDO_MAP,)), (node.tpdo, TPDO_MAPS)):
            for number, pdo_map in maps.items():
                pdo_map.clear()
                pdo_map.enabled = number <= len(layout)
                if pdo_map.enabled:
                    for index in layout[number - 1]:
                        pdo_map.add_variable(index)
                    pdo_map.trans_type = rpdo_type if maps is node.rpdo else SYNCHRONOUS
            maps.save()
        for j, pdo_map in enumerate(node.tpdo[n] for n in range(1, len(TPDO_MAPS) + 1)):
            pdo_map.add_callback(lambda m, k=k, j=j: self._on_tpdo(k, j, m))

    def enable(self, target: State = State.OPERATION_ENABLED, max_cycles: int = 20) -> Reading:
        """SYNC cycles with zero torque until every drive is in ``target`` (operation
        enabled, or switched on: powered, brake closed, for ``release``); the reading of
        the first such SYNC. DriveStartError naming the drives that did not get there
        (their states, error codes)."""
        reading = None
        for _ in range(max_cycles):
            if reading is not None and all(st is target for st in reading.states):
                return reading
            states = reading.states if reading else [None] * self.settings.n
            self.controlwords = [seq.next(st, target) if st is not None else
                                 CONTROLWORD[Command.DISABLE_VOLTAGE] for seq, st in zip(self.sequencers, states)]
            reading = self.exchange([0] * self.settings.n)
            if reading.missed:
                raise DriveStartError("; ".join(self._trip_pdo(k).text() for k in reading.missed))
        late = [f"{self.settings.names[k]} {st.label if st else 'unknown'}"
                + (f" ({error_text(self.emcy[k])})" if self.emcy[k] else "")
                for k, st in enumerate(reading.states) if st is not target]
        raise DriveStartError(f"drives not {target.label} after {max_cycles} cycles: {', '.join(late)}")

    def home(self, max_s: float = 30.0) -> list[Reading]:
        """Home the drives (the machine file's ``drives.homing``; nothing without one):
        each group in its turn in CiA 402 homing mode (0x6098 method, 0x607C the position
        at the mark, 0x6099 speed), started by controlword bit 4's rising edge, until
        every drive of it reports homing completed (statusword bits 10, 12). A drive not
        homed yet waits free (cyclic synchronous torque, 0), one homed holds (its homing
        mode's position loop), so that a parallel machine stays assembled. Then every
        drive switched on, brakes closed, in cyclic synchronous torque. The readings of
        the homing cycles (what the drive interface records); DriveStartError naming a
        drive that fails (its homing status, its trip)."""
        s = self.settings
        if not s.homing_methods:
            return []
        n, readings, homed = s.n, [], set()
        first = set(s.homing_order[0])
        for k, node in enumerate(self.nodes):
            node.sdo[0x6060].raw = int(Mode.HOMING if k in first else Mode.CYCLIC_SYNC_TORQUE)
        self.enable(State.SWITCHED_ON)                     # powered, brakes closed
        for group in s.homing_order:
            for k in group:
                sc, node = s.scaling[k], self.nodes[k]
                node.sdo[0x6098].raw = s.homing_methods[k]
                node.sdo[0x607C].raw = sc.position_to_drive(s.home_positions[k])
                speed = round(s.homing_speed * sc.counts_per_unit)
                node.sdo[0x6099][1].raw = node.sdo[0x6099][2].raw = speed
                node.sdo[0x6060].raw = int(Mode.HOMING)
            # the group's bit 4 rises (enabling it at the same SYNC the first time)
            self.controlwords = [CONTROLWORD[Command.ENABLE_OPERATION] | (CW_HOMING_START if k in homed or k in group
                                                                          else 0) for k in range(n)]
            deadline = time.monotonic() + max_s
            while True:
                reading = self.exchange([0] * n)
                readings.append(reading)
                trips = [t for t in self.check(reading) if t.cause is not TripCause.DRIVE_DISABLED or
                         reading.states[t.drive] not in (State.SWITCHED_ON, State.OPERATION_ENABLED)]
                if trips:
                    raise DriveStartError(f"homing: {trips[0].text()}")
                status = {k: homing_status(reading.statuswords[k]) for k in group}
                failed = [k for k, st in status.items()
                          if st in (HomingStatus.ERROR_MOVING, HomingStatus.ERROR_STOPPED)]
                if failed:
                    raise DriveStartError("homing: " + ", ".join(
                        f"drive {s.names[k]} (node {s.node_ids[k]}) method {s.homing_methods[k]}: "
                        f"{status[k].name.lower().replace('_', ' ')}" for k in failed))
                if all(st is HomingStatus.COMPLETED for st in status.values()) and \
                        all(reading.states[k] is State.OPERATION_ENABLED for k in group):
                    break
                if time.monotonic() > deadline:
                    late = ", ".join(f"{s.names[k]} {st.name.lower()}" for k, st in status.items()
                                     if st is not HomingStatus.COMPLETED)
                    raise DriveStartError(f"homing: not complete within {max_s:g} s: {late}")
            homed.update(group)
        self.controlwords = [CONTROLWORD[Command.SWITCH_ON]] * n     # disable operation: brakes close
        readings.append(self.exchange([0] * n))
        for node in self.nodes:
            node.sdo[0x6060].raw = int(Mode.CYCLIC_SYNC_TORQUE)
        self.homed = True
        return readings

    def release(self) -> None:
        """From the next cycle on, every drive switched on is enabled with the target
        of that cycle: its brake opens as its first force acts (no cycle at zero
        torque on a loaded machine)."""
        self.controlwords = [CONTROLWORD[Command.ENABLE_OPERATION]] * self.settings.n

    # -------------------------------------------------------------------- cycle
    def cycle(self, forces) -> Reading:
        """One exchange with the drives following ``forces`` (SI); quick stop after
        ``quick_stop``. Refused (FieldError) before the drives are homed: their
        positions are not the machine's."""
        if not self.homed:
            raise FieldError("drives", "not homed: motion commands are refused until the drives are homed "
                             "(CanopenMaster.home, the machine file's drives.homing)")
        targets = [sc.force_to_drive(f) for sc, f in zip(self.settings.scaling, forces)]
        return self.exchange([0] * len(targets) if self.stopping else targets)

    def exchange(self, targets: list[int]) -> Reading:
        """RPDOs (the current controlwords, ``targets`` in drive units), SYNC, TPDOs."""
        for node, word, target in zip(self.nodes, self.controlwords, targets):
            rpdo = node.rpdo[1]
            rpdo[0].raw = word
            rpdo[1].raw = target
            rpdo.transmit()
        with self.cond:
            for flags in self.arrived:
                flags[:] = [False] * len(flags)
        self.network.sync.transmit()
        self.syncs += 1
        deadline = time.monotonic() + self.pdo_timeout_s
        awaited = [k for k in range(len(self.arrived)) if k not in self.lost]
        with self.cond:
            while not all(all(self.arrived[k]) for k in awaited):
                left = deadline - time.monotonic()
                if left <= 0.0:
                    break
                self.cond.wait(left)
            missed = [k for k, flags in enumerate(self.arrived) if not all(flags)]
            values = [dict(v) for v in self.values]
        self.lost.update(missed)                 # not waited for again: the machine stops on it
        s = self.settings.scaling
        words = [v[0x6041] for v in values]
        return Reading([sc.position_from_drive(v[0x6064]) for sc, v in zip(s, values)],
                       [sc.velocity_from_drive(v[0x606C]) for sc, v in zip(s, values)],
                       [sc.force_from_drive(v[0x6077]) for sc, v in zip(s, values)],
                       words, [decode_state(w) for w in words], [bool(w & 0x800) for w in words], missed)

    # -------------------------------------------------------------- supervision
    def check(self, reading: Reading) -> list[DriveTrip]:
        """What the reading and the bus say is wrong, the first cause first (module docstring)."""
        found = []
        for k, code in enumerate(self.emcy):
            if code:
                found.append(self._trip(k, TripCause.DRIVE_FAULT, "sent an emergency (EMCY)", code))
        for k in reading.missed:
            found.append(self._trip_pdo(k))
        for k, state in enumerate(reading.states):
            if k in reading.missed or state is State.OPERATION_ENABLED:
                continue
            if state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
                found.append(self._trip(k, TripCause.DRIVE_FAULT, f"is in {state.label}", self._error_code(k)))
            elif state is None:
                found.append(self._trip(k, TripCause.DRIVE_FAULT, f"sent statusword 0x{reading.statuswords[k]:04X}, "
                                        f"which codes no CiA 402 state"))
            elif not self.stopping:
                found.append(self._trip(k, TripCause.DRIVE_DISABLED, f"left operation enabled: {state.label}"))
        now = time.monotonic()
        for k, watchdog in enumerate(self.heartbeats):
            silence = watchdog.silence_s(now)
            limit = self.heartbeat_factor * self.settings.heartbeat_s
            if silence is not None and silence > limit:
                found.append(self._trip(k, TripCause.HEARTBEAT_LOST,
                                        f"sent no heartbeat for {silence * 1e3:.0f} ms (its period "
                                        f"{self.settings.heartbeat_s * 1e3:g} ms, limit {limit * 1e3:g} ms)"))
            elif self.nmt_states[k] != NMT_OPERATIONAL:
                found.append(self._trip(k, TripCause.DRIVE_DISABLED, f"left NMT operational (heartbeat state "
                                        f"{self.nmt_states[k]})"))
        return found

    def _trip(self, k: int, cause: TripCause, detail: str, code: int = 0) -> DriveTrip:
        return DriveTrip(cause, k, self.settings.names[k], self.settings.node_ids[k], code, detail)

    def _trip_pdo(self, k: int) -> DriveTrip:
        return self._trip(k, TripCause.PDO_MISSED, f"sent no TPDO within {self.pdo_timeout_s * 1e3:g} ms of SYNC "
                          f"{self.syncs}")

    def _error_code(self, k: int) -> int:
        if self.emcy[k]:
            return self.emcy[k]
        try:
            return self.nodes[k].sdo[0x603F].raw
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError):
            return 0

    def quick_stop(self) -> list[str]:
        """Quick stop on every drive now (SDO), and in every RPDO from now on; the
        drives that did not confirm it (a silent one), as text."""
        self.stopping = True
        self.controlwords = [CONTROLWORD[Command.QUICK_STOP]] * self.settings.n
        failed = []
        for k, node in enumerate(self.nodes):
            try:
                node.sdo[0x6040].raw = CONTROLWORD[Command.QUICK_STOP]
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as exc:
                failed.append(f"drive {self.settings.names[k]} (node {self.settings.node_ids[k]}): {exc}")
        return failed
