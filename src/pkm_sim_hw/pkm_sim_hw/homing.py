"""Homing a machine's incremental encoders (no rclpy): the machine file's
``drives.homing`` (``homing_plan``: one reader for the simulated drives here and for
pkm_drives' CiA 402 drives), and ``home``, the homing of a simulated plant by its own
drives (sim_hw with ``encoder_offsets_m``): each group of drives in its turn runs its
HomingMotion (pkm_sim_hw.drives) on the plant, a drive not homed yet free, one homed
holding, until every drive of the group has found its mark; then every encoder's offset
is corrected, the plant holds, and its clock restarts at 0 (the run starts homed).

```yaml
drives:
  homing:
    method: [19, 19, 19, 35]      # CiA 402 homing methods (0x6098), one or one per drive
    order: [[0, 1, 2], [3]]       # groups homed one after the other
    home_position: home_pose      # each drive's position at its mark: one, one per drive, or
                                  # home_pose (the drives' positions at the machine's home pose)
    speed: 0.005                  # m/s towards the marks
    index_pitch: 0.005            # m between index pulses (33, 34)
```
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pkm_kinematics.config import FieldReader, MachineConfig
from pkm_kinematics.errors import ConfigError

from .drives import CURRENT_POSITION, HOME_SWITCH, INDEX_NEGATIVE, INDEX_POSITIVE, HomingMotion

__all__ = ["HOMING_METHODS", "HomingPlan", "HomingRecord", "homing_plan", "per_drive", "home"]

# CiA 402 homing methods (0x6098) the simulated drives run: what each homes on
HOMING_METHODS = {**dict.fromkeys(HOME_SWITCH, "home switch (its edge, from either side)"),
                  INDEX_NEGATIVE: "index pulse, negative direction", INDEX_POSITIVE: "index pulse, positive direction",
                  **dict.fromkeys(CURRENT_POSITION, "current position")}


@dataclass(frozen=True)
class HomingPlan:
    methods: tuple[int, ...]
    order: tuple[tuple[int, ...], ...]
    home_positions: tuple[float, ...]
    speed: float = 0.005
    index_pitch: float = 0.005


@dataclass
class HomingRecord:
    """What a homing did: the cycles it took, each drive's correction of its encoder
    (m or rad) and its status."""

    cycles: int
    shifts: list[float]
    status: list[str]

    def text(self, names) -> str:
        return f"homed in {self.cycles} cycles: " + ", ".join(
            f"{n} {s} ({d * 1e3:+.3f} mm)" for n, s, d in zip(names, self.status, self.shifts))


def per_drive(r: FieldReader, key: str, n: int, default=..., lo: float = 0.0, lo_open: bool = True,
              hi: float = math.inf) -> list[float]:
    """One number for every drive, or a list of ``n`` (ConfigError naming the entry)."""
    value = r.raw(key, default)
    if isinstance(value, list):
        if len(value) != n:
            raise ConfigError(r.field_name(key), f"expected one number or a list of {n}, got {value!r}")
        return [FieldReader({f"{key}[{k}]": v}, r.path).number(f"{key}[{k}]", lo=lo, lo_open=lo_open, hi=hi)
                for k, v in enumerate(value)]
    return [FieldReader({key: value}, r.path).number(key, lo=lo, lo_open=lo_open, hi=hi)] * n


def homing_plan(machine: MachineConfig) -> HomingPlan | None:
    """The machine file's ``drives.homing`` (None without one: absolute encoders)."""
    drives = machine.data.get("drives")
    if not isinstance(drives, dict) or "homing" not in drives:
        return None
    r = FieldReader(drives["homing"], "drives.homing")
    n = machine.model.n_legs
    methods = per_drive(r, "method", n, lo=-128, lo_open=False, hi=127)
    for k, m in enumerate(methods):
        if m not in HOMING_METHODS:
            raise ConfigError(r.field_name("method") + (f"[{k}]" if isinstance(r.raw("method"), list) else ""),
                              f"must be one of the CiA 402 methods {sorted(HOMING_METHODS)}, got {m:g}")
    order = r.raw("order", [list(range(n))])
    name = r.field_name("order")
    if not isinstance(order, list) or not all(isinstance(g, list) and g for g in order):
        raise ConfigError(name, f"expected a list of groups (lists of drive indices), got {order!r}")
    if sorted(d for g in order for d in g) != list(range(n)):
        raise ConfigError(name, f"must name each drive 0..{n - 1} once, got {order!r}")
    if r.raw("home_position") == "home_pose":
        home = machine.model.inverse_kinematics(machine.model.home).tolist()
    else:
        home = per_drive(r, "home_position", n, lo=-math.inf, lo_open=False)
    return HomingPlan(tuple(int(m) for m in methods), tuple(tuple(g) for g in order), tuple(home),
                      r.number("speed", 0.005, lo=0.0, lo_open=True, hi=1.0, unit="m/s"),
                      r.number("index_pitch", 0.005, lo=0.0, lo_open=True, hi=1.0, unit="m"))


def home(plant, plan: HomingPlan, mass_kg: float, max_s: float = 30.0, bandwidth_hz: float = 5.0) -> HomingRecord:
    """Home ``plant``'s drives by ``plan`` (the module docstring). ValueError naming a
    drive whose homing fails or does not end within ``max_s`` of simulated time."""
    n, dt = plant.n, plant.params.dt_s
    offsets = plant.encoders.offsets or [0.0] * n
    plant.pause_schedules()                            # the run's loads come with the run
    motions: dict[int, HomingMotion] = {}
    forces, cycles = [0.0] * n, 0
    for group in plan.order:
        for k in group:
            motions[k] = HomingMotion(plan.methods[k], plan.home_positions[k], plan.speed, mass_kg, dt,
                                      bandwidth_hz, plan.index_pitch)
        for _ in range(math.ceil(max_s / dt)):
            out = plant.step(forces)
            cycles += 1
            if plant.stopped:
                raise ValueError(f"homing: the plant stopped: {plant.stop_reason}")
            for k, motion in motions.items():
                reading = out.encoder_positions[k]
                forces[k] = motion.step(reading - offsets[k], reading, out.encoder_velocities[k])
                if motion.status == "error":
                    raise ValueError(f"homing: drive {plant.names[k]} method {plan.methods[k]} found no mark")
            if all(motions[k].status == "completed" for k in group):
                break
        else:
            late = [plant.names[k] for k in group if motions[k].status != "completed"]
            raise ValueError(f"homing: drives {', '.join(late)} not homed within {max_s:g} s")
    shifts = [motions[k].shift for k in range(n)]
    plant.encoders.offsets = [o + s for o, s in zip(offsets, shifts)]
    plant.homed = True
    plant.step([0.0] * n, hold=True)                  # brakes on; the encoders read the machine's positions
    plant.restart_clock()
    return HomingRecord(cycles, shifts, [motions[k].status for k in range(n)])
