"""Drive compensation tables (pure): what the geometric model leaves along each drive,
a screw's or a scale's repeatable error, as a table per drive applied to its encoder
reading (LinuxCNC's COMP_FILE is the anchor: a joint's nominal positions and their
trims, linear between them, at most 256 points).

    q_true = q + c(q),    c linear between the table's (position, correction) points,
                          held at the end values beyond them

A machine file carries its tables in a ``compensation`` section, one per drive that
has one, ``{q1: [[position, correction], ...], ...}`` in the file's ``length_unit``,
each table overlapping the drive's joint limits; pkm-calibrate identify writes them,
and each also as a LinuxCNC comp file (COMP_FILE_TYPE 0: lines "nominal actual
actual", the position the joint reports and where it really is, moving forward and
back: the same, no backlash modelled; in mm).
The controller applies them to the readings (and the velocities by the slope) before
anything else sees them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import LENGTH_UNITS
from .errors import ConfigError

__all__ = ["DriveTable", "Compensation", "compensation_of", "comp_file_text", "read_comp_file", "MAX_POINTS"]

MAX_POINTS = 256        # LinuxCNC's limit per joint
MAX_CORRECTION_M = 0.01


@dataclass(frozen=True)
class DriveTable:
    positions: np.ndarray      # ascending (m)
    corrections: np.ndarray    # (m)

    def __post_init__(self):
        p, c = np.asarray(self.positions, dtype=float), np.asarray(self.corrections, dtype=float)
        if p.ndim != 1 or p.shape != c.shape or not 2 <= len(p) <= MAX_POINTS:
            raise ConfigError("compensation", f"a table is 2 to {MAX_POINTS} (position, correction) points, got "
                                              f"{len(p)} positions and {len(c)} corrections")
        if not (np.isfinite(p).all() and np.isfinite(c).all() and np.all(np.diff(p) > 0.0)):
            raise ConfigError("compensation", "positions must be finite and strictly ascending, corrections finite")
        if np.abs(c).max() > MAX_CORRECTION_M:
            raise ConfigError("compensation", f"a correction of {np.abs(c).max():.4g} m: at most "
                                              f"{MAX_CORRECTION_M:g} m (a screw's error, not a geometry's)")
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "corrections", c)

    def correction(self, q) -> np.ndarray:
        return np.interp(q, self.positions, self.corrections)

    def slope(self, q) -> np.ndarray:
        """dc/dq at q (0 beyond the ends)."""
        q = np.asarray(q, dtype=float)
        k = np.clip(np.searchsorted(self.positions, q) - 1, 0, len(self.positions) - 2)
        inside = (q >= self.positions[0]) & (q <= self.positions[-1])
        step = np.diff(self.corrections)[k] / np.diff(self.positions)[k]
        return np.where(inside, step, 0.0)


@dataclass(frozen=True)
class Compensation:
    """The tables of a machine's drives, in the drives' order (None: no table)."""
    tables: tuple

    def positions(self, q) -> np.ndarray:
        """The true drive positions of readings ``q`` (n,)."""
        q = np.asarray(q, dtype=float)
        return q + np.array([0.0 if t is None else float(t.correction(v)) for t, v in zip(self.tables, q)])

    def velocities(self, q, qdot) -> np.ndarray:
        """The true drive velocities of reading rates ``qdot`` at ``q``: (1 + c'(q)) qdot."""
        scale = np.array([1.0 if t is None else 1.0 + float(t.slope(v)) for t, v in zip(self.tables, q)])
        return scale * np.asarray(qdot, dtype=float)


def compensation_of(config) -> Compensation | None:
    """The ``compensation`` section of a machine file (a MachineConfig), or None.
    ConfigError naming the drive of a bad table (not two columns, outside its joint
    limits) or an unknown drive."""
    section = config.data.get("compensation")
    if not section:
        return None
    names = list(config.model.leg_names)
    if not isinstance(section, dict):
        raise ConfigError("compensation", f"a mapping drive -> [[position, correction], ...], got {section!r}")
    unknown = [k for k in section if k not in names]
    if unknown:
        raise ConfigError("compensation", f"{unknown[0]!r} is not a drive of {config.name} ({', '.join(names)})")
    unit = LENGTH_UNITS[config.data.get("length_unit", "m")]
    model = config.model
    tables = []
    for k, name in enumerate(names):
        rows = section.get(name)
        if rows is None:
            tables.append(None)
            continue
        try:
            arr = np.asarray(rows, dtype=float)
            if arr.ndim != 2 or arr.shape[1] != 2:
                raise ConfigError("compensation", f"rows of [position, correction], got shape {arr.shape}")
            table = DriveTable(arr[:, 0] * unit, arr[:, 1] * unit)
        except (ValueError, IndexError) as exc:
            raise ConfigError(f"compensation.{name}", str(exc).split(": ", 1)[-1]) from None
        lower, upper = float(model.joint_lower[k]), float(model.joint_upper[k])
        if table.positions[-1] < lower or table.positions[0] > upper:
            unit_name = config.data.get("length_unit", "m")
            raise ConfigError(f"compensation.{name}", f"the table's positions [{table.positions[0] / unit:g}, "
                                                      f"{table.positions[-1] / unit:g}] miss the drive's joint limits "
                                                      f"[{lower / unit:g}, {upper / unit:g}] ({unit_name})")
        tables.append(table)
    return Compensation(tuple(tables))


def comp_file_text(table: DriveTable, unit_m: float = 1e-3) -> str:
    """A LinuxCNC comp file (COMP_FILE_TYPE 0: "nominal actual actual", the reported and
    the real position) of ``table``, in machine units of ``unit_m`` (default mm)."""
    return "".join(f"{p / unit_m:.6f} {(p + c) / unit_m:.6f} {(p + c) / unit_m:.6f}\n"
                   for p, c in zip(table.positions, table.corrections))


def read_comp_file(text: str, unit_m: float = 1e-3) -> DriveTable:
    """The table of a LinuxCNC comp file's text (COMP_FILE_TYPE 0; moving forward)."""
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith(("#", ";")):
            continue
        if len(words) != 3:
            raise ConfigError("comp_file", f"line {number}: expected 'nominal actual-forward actual-reverse', got "
                                           f"{line!r}")
        nominal, actual = float(words[0]) * unit_m, float(words[1]) * unit_m
        rows.append([nominal, actual - nominal])
    arr = np.asarray(rows, dtype=float).reshape(-1, 2)
    return DriveTable(arr[:, 0], arr[:, 1])
