"""Virtual CiA 402 servo drives on any python-can bus (a library: tests and users put
them on a bus; the graph runs over them).

A ``VirtualDrive`` is ``canopen``'s ``LocalNode`` with a CiA 402 object dictionary
(``eds/cia402_servo.eds`` by default, or a drive's own EDS) and the drive's side of
the state machine (cia402.DriveStateMachine). It answers SDOs and NMT as ``canopen``
does, sends its heartbeat (0x1017), its EMCY on a fault, and its TPDOs after each SYNC.
What it does with its RPDOs is CiA 402's:

- it follows the target torque (0x6071, limited by 0x6072) only in "operation
  enabled" and in cyclic synchronous torque mode; in every other state its power
  stage is off and its holding brake closed;
- a quick stop (controlword) closes the brake at once (the stop of a braked axis),
  then "switch on disabled" (quick stop option code 1-2) or stays (5-6);
- a fault (an injected one, or the master's heartbeat lost when 0x1016 asks for it)
  starts the fault reaction (the brake), is latched in "fault" with its code in 0x603F
  and sent as EMCY, until a fault reset (controlword bit 7's rising edge);
- an RPDO of a synchronous transmission type (0x1400 sub 2 <= 240) acts at the SYNC
  after it, an asynchronous one (254, 255) as it arrives.

The physics is not the drive's: a ``VirtualMachine`` (below) owns the drives of one
machine and an ``Axes`` model (the simulated plant, or independent masses for a drive
on a bench) and, at each SYNC, gives every drive's force to the model, steps it once,
and has each drive report its encoder (0x6064, 0x606C) and torque (0x6077).

Injectable faults (``VirtualDrive.inject``): ``over_current`` (0x2310),
``following_error`` (0x8611), ``encoder`` (0x7305; the position freezes),
``heartbeat_lost`` (the heartbeat stops, the drive works on), ``silent`` (the drive
stops answering anything: a cut cable; its own communication watchdog brakes it),
``local_stop`` (its own quick stop input: it leaves operation enabled without a fault).
"""

from __future__ import annotations

import enum
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import canopen

from pkm_kinematics.errors import FieldError
from pkm_sim_hw.drives import HomingMotion

from .cia402 import DriveStateMachine, HomingStatus, Mode, QuickStopOption, State, homing_bits, statusword
from .drive_config import AxisScaling

__all__ = ["DEFAULT_EDS", "InjectedFault", "FAULT_CODES", "VirtualDrive", "Axes", "MassAxes", "VirtualMachine",
           "parse_drive_faults", "HomingSetup", "Sample"]

DEFAULT_EDS = Path(__file__).with_name("eds") / "cia402_servo.eds"


class InjectedFault(str, enum.Enum):
    OVER_CURRENT = "over_current"
    FOLLOWING_ERROR = "following_error"
    ENCODER = "encoder"
    HEARTBEAT_LOST = "heartbeat_lost"
    SILENT = "silent"
    LOCAL_STOP = "local_stop"          # the drive's own quick stop input (no fault): it leaves operation enabled


# the error code (0x603F, EMCY) and error register bit (0x1001) of each drive fault
FAULT_CODES = {
    InjectedFault.OVER_CURRENT: (0x2310, 0x02),
    InjectedFault.FOLLOWING_ERROR: (0x8611, 0x20),
    InjectedFault.ENCODER: (0x7305, 0x01),
}
HEARTBEAT_CONSUMER_FAULT = (0x8130, 0x10)      # the master's heartbeat lost (0x1016)
GENERIC_ERROR = 0x01
HOMING_STATUS = {"in_progress": HomingStatus.IN_PROGRESS, "attained": HomingStatus.ATTAINED,
                 "completed": HomingStatus.COMPLETED, "error": HomingStatus.ERROR_STOPPED}
POWERED = (State.SWITCHED_ON, State.OPERATION_ENABLED)      # the machine's clock runs from here on


@dataclass
class Sample:
    """What a drive reports at a SYNC, in SI units (the drive converts)."""

    position: float              # the encoder's reading (its offset included, until the drive is homed)
    velocity: float
    force: float
    true: float | None = None    # the reading without the offset, where homing marks are (None: = position)


@dataclass(frozen=True)
class HomingSetup:
    """The drive's own tuning for its homing motion (pkm_sim_hw.drives.HomingMotion):
    the mass it moves, its position loop's bandwidth, its encoder's index pitch, the
    SYNC period; the method, home position and speed come from the master (SDO)."""

    mass_kg: float = 10.0
    bandwidth_hz: float = 5.0
    pitch: float = 0.005
    dt_s: float = 0.002
    default_speed: float = 0.005         # m/s when 0x6099 says 0


class VirtualDrive:
    """One virtual CiA 402 drive, node ``node_id`` on ``network`` (a canopen.Network,
    connected to a python-can bus), scaling SI <-> drive units with ``scaling``."""

    def __init__(self, network: canopen.Network, node_id: int, scaling: AxisScaling, eds: str | Path = DEFAULT_EDS,
                 name: str = "", homing: HomingSetup = HomingSetup()):
        self.name = name or f"drive {node_id}"
        self.scaling, self.homing_setup = scaling, homing
        self.homing_motion: HomingMotion | None = None
        self.homing_force = 0.0
        self.shift = 0.0                        # added to the encoder's reading once homed (m or rad)
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
        network.add_node(self.node)
        self.network = network
        self.machine = DriveStateMachine(QuickStopOption(self.node.sdo[0x605A].raw))
        self.mode = Mode(self.node.sdo[0x6060].raw)
        self.lock = threading.Lock()            # the notifier thread (SDO, RPDO) vs the SYNC's
        self.received_controlword = 0
        self.received_target = 0                # 0x6071 of the last RPDO
        self.latched_target = 0                 # a synchronous RPDO's value, effective from the SYNC after it
        self.pending: list[InjectedFault] = []
        self.silent = False
        self.encoder_frozen: float | None = None
        self.sample = Sample(0.0, 0.0, 0.0)
        self.homing = HomingStatus.INTERRUPTED
        self.errors: list[str] = []             # exceptions in callbacks (canopen logs and drops them)
        self.node.add_write_callback(self._on_sdo_write)
        self.node.add_read_callback(self._on_sdo_read)
        self.sync_rpdo = True                   # start_pdos: from the RPDOs' transmission type
        self.pdos_started = False
        network.subscribe(0, self._on_nmt)        # after the node's own NMT slave (add_node)
        self.machine.initialised()                # self-test passed: switch on disabled

    # --------------------------------------------------------------- bus side
    def boot(self) -> None:
        """Power on: the boot-up message, pre-operational (the heartbeat starts if 0x1017 > 0)."""
        self.node.nmt.state = "INITIALISING"
        self.node.nmt.state = "PRE-OPERATIONAL"

    def _on_nmt(self, can_id, data, timestamp) -> None:
        if self.node.nmt.state == "OPERATIONAL" and not self.pdos_started:
            try:
                self.start_pdos()
            except Exception as exc:             # canopen's listener would log and drop it
                self.errors.append(f"start_pdos: {type(exc).__name__}: {exc}")

    def _on_sdo_write(self, index: int, subindex: int, od, data: bytes) -> None:
        value = od.decode_raw(data)
        with self.lock:
            if index == 0x6040:             # by SDO a controlword acts as it comes (not at a SYNC)
                self._controlword(value)
            elif index == 0x6071:
                self.received_target = value
            elif index == 0x6060:
                self.mode = Mode(value)
            elif index == 0x605A:
                self.machine.quick_stop_option = QuickStopOption(value)

    def _on_sdo_read(self, index: int, subindex: int, od):
        live = {0x6041: self.statusword, 0x6061: lambda: int(self.mode), 0x603F: lambda: self.machine.error_code,
                0x6064: lambda: self.scaling.position_to_drive(self.sample.position + self.shift),
                0x606C: lambda: round(self.sample.velocity * self.scaling.counts_per_unit),
                0x6077: lambda: self.scaling.force_to_drive(self.sample.force),
                0x1001: self.error_register}
        return live[index]() if index in live else None

    def _on_rpdo(self, pdo_map) -> None:
        if self.silent:
            return
        with self.lock:
            for var in pdo_map:
                if var.index == 0x6040:
                    self.received_controlword = var.raw
                elif var.index == 0x6071:
                    self.received_target = var.raw
                elif var.index == 0x6060:
                    self.mode = Mode(var.raw)
            if not self.sync_rpdo:               # an asynchronous RPDO acts as it comes
                self._controlword(self.received_controlword)
                self.latched_target = self.received_target

    def start_pdos(self) -> None:
        """Read the PDO configuration the master wrote (or the EDS's) and listen to the RPDOs."""
        self.node.rpdo.read(from_od=False)
        self.node.tpdo.read(from_od=False)
        for pdo_map in self.node.rpdo.values():
            if pdo_map.enabled:
                pdo_map.add_callback(self._on_rpdo)
                pdo_map.subscribe()
        self.pdos_started = True
        self.sync_rpdo = all(m.trans_type is not None and m.trans_type <= 240
                             for m in self.node.rpdo.values() if m.enabled)

    @property
    def operational(self) -> bool:
        return self.node.nmt.state == "OPERATIONAL" and not self.silent

    def error_register(self) -> int:
        code = self.machine.error_code
        if not code:
            return 0
        bit = next((b for c, b in list(FAULT_CODES.values()) + [HEARTBEAT_CONSUMER_FAULT] if c == code), 0)
        return GENERIC_ERROR | bit

    def statusword(self) -> int:
        mode_bits, reached = 0, False
        if self.mode is Mode.HOMING:
            mode_bits, reached = homing_bits(self.homing)
        elif self.machine.state is State.OPERATION_ENABLED and self.mode is Mode.CYCLIC_SYNC_TORQUE:
            mode_bits = 1 << 12                  # CST: the target torque is followed
        limited = abs(self.received_target) > self.scaling.max_per_mille
        return statusword(self.machine.state, mode_bits=mode_bits, target_reached=reached, internal_limit=limited)

    # ---------------------------------------------------------- SYNC, physics
    def inject(self, fault: InjectedFault | str) -> None:
        """A fault from the next SYNC on (the module docstring)."""
        with self.lock:
            self.pending.append(InjectedFault(fault))

    def fault(self, code: int, register_bit: int) -> None:
        """Transition 13 and the EMCY (once: a fault during a fault keeps the first)."""
        if self.machine.fault(code) and not self.silent:
            self.node.emcy.send(code, GENERIC_ERROR | register_bit)

    def force(self) -> float | None:
        """The force this drive applies over the period ending at this SYNC; None: its
        brake holds. Called once per SYNC, before the physics steps."""
        with self.lock:
            target = self.latched_target
        if not self.machine.torque_enabled:
            return None
        limit = self.scaling.force_from_drive(self.scaling.max_per_mille)
        if self.mode is Mode.HOMING:              # its own position loop (0 before the homing starts)
            return max(-limit, min(limit, self.homing_force)) if self.homing_motion is not None else 0.0
        if self.mode is not Mode.CYCLIC_SYNC_TORQUE:
            return None
        return self.scaling.force_from_drive(max(-self.scaling.max_per_mille, min(self.scaling.max_per_mille, target)))

    def _controlword(self, word: int) -> None:
        previous = self.machine.last_controlword
        made = self.machine.on_controlword(word)
        if any(t.number == 15 for t in made) and not self.silent:
            self.encoder_frozen = None
            self.node.emcy.reset()             # fault reset: the error is gone
        if not self.machine.torque_enabled:
            if self.homing_motion is not None and self.homing is HomingStatus.IN_PROGRESS:
                self.homing = HomingStatus.INTERRUPTED
            self.homing_motion, self.homing_force = None, 0.0
        elif self.mode is Mode.HOMING and word & 0x10 and not previous & 0x10:
            self._start_homing()                 # bit 4's rising edge in operation enabled

    def _start_homing(self) -> None:
        """The method (0x6098), home offset (0x607C: the position at the mark) and
        speed (0x6099 sub 2) the master wrote; the motion starts at the next sample."""
        sc, setup = self.scaling, self.homing_setup
        speed = sc.velocity_from_drive(self.node.sdo[0x6099][2].raw) or setup.default_speed
        try:
            self.homing_motion = HomingMotion(self.node.sdo[0x6098].raw,
                                              sc.position_from_drive(self.node.sdo[0x607C].raw), speed,
                                              setup.mass_kg, setup.dt_s, setup.bandwidth_hz, setup.pitch)
            self.homing, self.homing_force = HomingStatus.IN_PROGRESS, 0.0
        except ValueError:                       # a method this drive does not run
            self.homing_motion, self.homing = None, HomingStatus.ERROR_STOPPED

    def after_step(self, sample: Sample) -> None:
        """The SYNC's instant: a quick stop or fault reaction of the period ends, the
        injected faults happen, the RPDO values received act (synchronous RPDOs), and
        the TPDOs report ``sample``."""
        # a stop that held through the period is complete (each state is seen for a SYNC at least)
        self.machine.fault_reaction_done() or self.machine.quick_stop_done()
        with self.lock:
            pending, self.pending = self.pending, []
            if self.sync_rpdo:
                self._controlword(self.received_controlword)
                self.latched_target = self.received_target
        for fault in pending:
            if fault is InjectedFault.HEARTBEAT_LOST:
                self.node.nmt.stop_heartbeat()
            elif fault is InjectedFault.LOCAL_STOP:
                with self.lock:
                    self._controlword(0x02)      # as its quick stop input does
            elif fault is InjectedFault.SILENT:
                self.silent = True
                self.node.nmt.stop_heartbeat()
                self.node.remove_network()       # no SDO, NMT, PDO or EMCY any more
                self.machine.fault(0x8130)       # its own watchdog: no more RPDOs
            else:
                if fault is InjectedFault.ENCODER:
                    self.encoder_frozen = sample.position
                self.fault(*FAULT_CODES[fault])
        if self.encoder_frozen is not None:
            sample = Sample(self.encoder_frozen, 0.0, sample.force)
        self.sample = sample
        if self.homing_motion is not None and self.mode is Mode.HOMING and self.machine.torque_enabled:
            self._homing_step(sample)
        if self.operational:
            self._send_tpdos()

    def _homing_step(self, sample: Sample) -> None:
        motion = self.homing_motion
        self.homing_force = motion.step(sample.position if sample.true is None else sample.true, sample.position,
                                        sample.velocity)
        self.homing = HOMING_STATUS[motion.status]
        if motion.latched is not None:
            self.shift = motion.shift

    def _send_tpdos(self) -> None:
        s = self.scaling
        values = {0x6041: self.statusword(), 0x6061: int(self.mode),
                  0x6064: s.position_to_drive(self.sample.position + self.shift),
                  0x606C: round(self.sample.velocity * s.counts_per_unit), 0x6077: s.force_to_drive(self.sample.force),
                  0x603F: self.machine.error_code}
        for pdo_map in self.node.tpdo.values():
            if not pdo_map.enabled:
                continue
            for var in pdo_map:
                var.raw = values.get(var.index, 0)
            pdo_map.transmit()


def parse_drive_faults(text: str, n: int) -> list[tuple[int, InjectedFault, float]]:
    """``drive_faults`` as (drive, fault, at_s); FieldError naming a bad entry."""
    out = []
    for item in (t.strip() for t in text.split(",") if t.strip()):
        parts = item.split(":")
        try:
            drive, kind = int(parts[0]), InjectedFault(parts[1])
            at_s = float(parts[2]) if len(parts) > 2 else 0.0
        except (IndexError, ValueError):
            raise FieldError("drive_faults", f"expected '<drive>:<kind>[:<at_s>]' with kind one of "
                             f"{[f.value for f in InjectedFault]}, got {item!r}") from None
        if not 0 <= drive < n or len(parts) > 3 or not (math.isfinite(at_s) and at_s >= 0.0):
            raise FieldError("drive_faults", f"drive in [0, {n - 1}], at_s >= 0, got {item!r}")
        out.append((drive, kind, at_s))
    return sorted(out, key=lambda f: f[2])


class Axes(Protocol):
    """The physics behind a machine's drives (one model for all: a parallel machine
    couples them). ``step(forces)``: advance one period with each drive's force, None
    where its brake holds; returns each drive's sample after it."""

    n: int

    def step(self, forces: list[float | None]) -> list[Sample]: ...

    def samples(self) -> list[Sample]: ...

    def restart(self) -> None:
        """The run starts here: its clock at 0 (the state kept)."""


class MassAxes:
    """Independent drives each moving a mass with viscous friction (a drive on a test
    bench), semi-implicit Euler, a braked one stopped where it is."""

    def __init__(self, n: int, mass_kg: float = 5.0, friction_ns_per_m: float = 20.0, dt_s: float = 0.001,
                 start=(), offsets=()):
        self.n, self.mass, self.friction, self.dt = n, mass_kg, friction_ns_per_m, dt_s
        self.position, self.velocity, self.applied = list(start) or [0.0] * n, [0.0] * n, [0.0] * n
        self.offsets = list(offsets) or [0.0] * n          # the encoders' (until homed)

    def step(self, forces):
        for i, f in enumerate(forces):
            if f is None:
                self.velocity[i], self.applied[i] = 0.0, 0.0
                continue
            self.velocity[i] += (f - self.friction * self.velocity[i]) / self.mass * self.dt
            self.position[i] += self.velocity[i] * self.dt
            self.applied[i] = f
        return self.samples()

    def samples(self):
        return [Sample(p + o, v, f, p) for p, v, f, o in zip(self.position, self.velocity, self.applied, self.offsets)]

    def restart(self) -> None:
        pass


class VirtualMachine:
    """The drives of one machine on one network and the physics they move. The physics
    runs from the first SYNC after which every drive has been powered (switched on or
    enabled): before it a SYNC only samples; from it on each SYNC (COB-ID 0x80) steps
    ``axes`` once with the drives' forces and has every drive report. The run's clock,
    ``steps``, restarts at 0 at every SYNC after which all drives are switched on (not
    enabled) in cyclic synchronous torque: where the master leaves them for the
    controller, after homing
    (hardware.CanopenHardware.start: its step 0 is that SYNC too); the axes' clock with
    it (``restart``). ``on_step(k)``, if given, is called after each step of the run in
    cyclic synchronous torque (not while homing)."""

    def __init__(self, network: canopen.Network, axes: Axes, node_ids, scaling, eds: str | Path = DEFAULT_EDS,
                 names=(), on_step=None, homing: HomingSetup = HomingSetup()):
        self.axes, self.on_step = axes, on_step
        self.drives = [VirtualDrive(network, nid, sc, eds, name=names[k] if names else "", homing=homing)
                       for k, (nid, sc) in enumerate(zip(node_ids, scaling))]
        self.syncs = 0
        self.powered = False
        self.steps: int | None = None           # the run's step count (None: not started)
        self.errors: list[str] = []
        network.subscribe(0x80, self._on_sync)

    def boot(self) -> None:
        for drive in self.drives:
            drive.boot()

    def _on_sync(self, can_id, data, timestamp) -> None:
        try:
            if not self.powered:
                samples = self.axes.samples()
            else:
                samples = self.axes.step([d.force() for d in self.drives])
            self.syncs += 1
            for drive, sample in zip(self.drives, samples):
                drive.after_step(sample)
            states = [d.machine.state for d in self.drives]
            self.powered = self.powered or all(st in POWERED for st in states)
            if all(st is State.SWITCHED_ON for st in states) and \
                    all(d.mode is Mode.CYCLIC_SYNC_TORQUE for d in self.drives):
                self.steps = 0
                self.axes.restart()
            elif self.steps is not None:
                self.steps += 1
            if self.steps is not None and self.on_step is not None and \
                    all(d.mode is Mode.CYCLIC_SYNC_TORQUE for d in self.drives):
                self.on_step(self.steps)
        except Exception as exc:                 # canopen's listener would log and drop it
            self.errors.append(f"{type(exc).__name__}: {exc}")
            raise
