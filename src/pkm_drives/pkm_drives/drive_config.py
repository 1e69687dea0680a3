"""The ``drives`` section of a machine file (pure): each drive's node ID, its scaling
between SI and drive units, its homing, and the bus.

```yaml
drives:
  bus: {interface: socketcan, channel: can0, bitrate: 1000000}
  heartbeat_ms: 100               # each drive's producer heartbeat (0x1017); 3 missed: lost
  rpdo: synchronous               # RPDOs act at the next SYNC (all drives at once, one cycle late)
                                  # or on_arrival (as they come: no cycle of delay)
  node_ids: [1, 2, 3, 4]          # one per leg, in the legs' order, 1-127, unique
  counts_per_unit: 1.0e6          # encoder counts per m (rail, strut) or rad; one, or one per drive
  rated_force: 700.0              # N (N m): the drive's 1000 per mille (0x6076); one or one per drive
  max_force: 2000.0               # N (N m): the drive's torque limit (0x6072); one or one per drive
  homing:                         # incremental encoders: homed before any motion (none: absolute ones)
    method: [19, 19, 19, 35]      # CiA 402 homing method (0x6098); one or one per drive
    order: [[0, 1, 2], [3]]       # groups homed one after the other (a drive not homed yet is free,
                                  # one homed holds): three switches fix ARCHI's pose, the fourth drive
                                  # then takes its position there (35: current position)
    home_position: home_pose      # m (rad): each drive's position at its mark; one, one per drive, or
                                  # home_pose: the drives' positions at the machine's home pose
    speed: 0.005                  # m/s (rad/s) towards the marks
    index_pitch: 0.005            # m (rad) between index pulses (methods 33, 34)
```

Every value is checked when read; a bad one raises ``ConfigError`` naming its dotted
path (``drives.node_ids[2]: ...``) before anything is opened or moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pkm_kinematics.config import FieldReader, MachineConfig
from pkm_kinematics.errors import ConfigError
from pkm_sim_hw.homing import HOMING_METHODS, HomingPlan, homing_plan, per_drive

# HOMING_METHODS: pkm_sim_hw.homing's (one reader of drives.homing for both kinds of drives)
__all__ = ["AxisScaling", "BusSettings", "DriveSettings", "HOMING_METHODS", "drive_settings"]

INT16 = (-32768, 32767)
INT32 = (-(1 << 31), (1 << 31) - 1)

@dataclass(frozen=True)
class AxisScaling:
    """SI <-> drive units of one drive: positions in encoder counts (INT32, 0x6064),
    velocities in counts/s (0x606C), forces in per mille of the rated force (INT16,
    0x6071/0x6077), limited to ``max_force``."""

    counts_per_unit: float
    rated_force: float
    max_force: float

    @property
    def max_per_mille(self) -> int:
        """The torque limit in drive units (0x6072)."""
        return min(INT16[1], int(self.max_force / self.rated_force * 1000.0))

    def force_to_drive(self, force: float) -> int:
        """Target torque (0x6071) of a force, clamped to the limit."""
        per_mille = round(force / self.rated_force * 1000.0) if math.isfinite(force) else 0
        return max(-self.max_per_mille, min(self.max_per_mille, per_mille))

    def force_from_drive(self, per_mille: int) -> float:
        return per_mille * self.rated_force / 1000.0

    def position_to_drive(self, q: float) -> int:
        return max(INT32[0], min(INT32[1], round(q * self.counts_per_unit)))

    def position_from_drive(self, counts: int) -> float:
        return counts / self.counts_per_unit

    def velocity_from_drive(self, counts_per_s: int) -> float:
        return counts_per_s / self.counts_per_unit


@dataclass(frozen=True)
class BusSettings:
    """The python-can bus of the drives: ``interface`` (socketcan on a real machine;
    virtual or remote here), ``channel``, ``bitrate``."""

    interface: str
    channel: str
    bitrate: int


@dataclass(frozen=True)
class DriveSettings:
    """A machine's drives (the module docstring's fields, per drive in legs' order)."""

    names: tuple[str, ...]
    node_ids: tuple[int, ...]
    scaling: tuple[AxisScaling, ...]
    homing_methods: tuple[int, ...]            # empty: no homing (absolute encoders)
    homing_order: tuple[tuple[int, ...], ...]
    home_positions: tuple[float, ...]
    heartbeat_s: float
    bus: BusSettings
    rpdo_synchronous: bool = True    # RPDOs act at the SYNC after them (else as they come)
    homing_speed: float = 0.005
    index_pitch: float = 0.005

    @property
    def n(self) -> int:
        return len(self.node_ids)


def _node_ids(r: FieldReader, n: int) -> tuple[int, ...]:
    value = r.raw("node_ids")
    name = r.field_name("node_ids")
    if not isinstance(value, list) or len(value) != n:
        raise ConfigError(name, f"expected a list of {n} node IDs (one per leg), got {value!r}")
    seen = {}
    for k, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 127:
            raise ConfigError(f"{name}[{k}]", f"must be an integer in [1, 127], got {v!r}")
        if v in seen:
            raise ConfigError(f"{name}[{k}]", f"node ID {v} is also drive {seen[v]}'s: each drive needs its own")
        seen[v] = k
    return tuple(value)


def drive_settings(machine: MachineConfig, bus_override: dict | None = None) -> DriveSettings:
    """The machine file's ``drives`` section, checked; ``bus_override`` (a scenario's
    ``interface``/``channel``/``bitrate``) replaces fields of its ``bus``."""
    n = machine.model.n_legs
    names = tuple(machine.model.leg_names)
    if "drives" not in machine.data:
        raise ConfigError("drives", f"machine {machine.name!r} has no drives section (node IDs, scaling, "
                          f"homing): docs/drives.md")
    r = FieldReader(machine.data["drives"], "drives")
    counts = per_drive(r, "counts_per_unit", n)
    rated = per_drive(r, "rated_force", n)
    max_force = per_drive(r, "max_force", n)
    for k, (rf, mf) in enumerate(zip(rated, max_force)):
        if mf / rf * 1000.0 > INT16[1]:
            raise ConfigError("drives.max_force", f"drive {k}: {mf:g} is {mf / rf * 1000.0:.0f} per mille of the "
                              f"rated force {rf:g}, over INT16's {INT16[1]}")
    plan = homing_plan(machine) or HomingPlan((), (), ())
    bus = dict(r.raw("bus", {}))
    bus.update(bus_override or {})
    b = FieldReader(bus, "drives.bus")
    bus_settings = BusSettings(b.string("interface", "socketcan"), str(b.raw("channel", "can0")),
                               int(b.number("bitrate", 1_000_000, lo=10_000, hi=1_000_000)))
    heartbeat_s = r.number("heartbeat_ms", 100.0, lo=0.0, lo_open=True, hi=65535.0, unit="ms") / 1000.0
    rpdo = r.choice("rpdo", ("synchronous", "on_arrival"), "synchronous")
    return DriveSettings(names, _node_ids(r, n),
                         tuple(AxisScaling(c, rf, mf) for c, rf, mf in zip(counts, rated, max_force)),
                         plan.methods, plan.order, plan.home_positions, heartbeat_s, bus_settings,
                         rpdo == "synchronous", plan.speed, plan.index_pitch)
