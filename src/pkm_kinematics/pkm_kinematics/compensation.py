"""Drive compensation tables (pure): what the geometric model leaves along each drive,
a screw's or a scale's repeatable error, as a table per drive applied to its encoder
reading (LinuxCNC's COMP_FILE is the anchor: a joint's nominal positions and their
trims, linear between them, at most 256 points).

    q_true = q + c(q),    c linear between the table's (position, correction) points,
                          held at the end values beyond them

A machine file carries its tables in a ``compensation`` section, one per drive that
has one, ``{q1: [[position, correction], ...], ...}`` (m); pkm-calibrate identify
writes them, and each also as a LinuxCNC comp file (COMP_FILE_TYPE 1: lines
"nominal forward-trim reverse-trim", the same trim both ways: no backlash modelled).
The controller applies them to the readings (and the velocities by the slope) before
anything else sees them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
    ConfigError naming the drive of a bad table or an unknown drive."""
    section = config.data.get("compensation")
    if not section:
        return None
    names = list(config.model.leg_names)
    if not isinstance(section, dict):
        raise ConfigError("compensation", f"a mapping drive -> [[position, correction], ...], got {section!r}")
    unknown = [k for k in section if k not in names]
    if unknown:
        raise ConfigError("compensation", f"{unknown[0]!r} is not a drive of {config.name} ({', '.join(names)})")
    tables = []
    for name in names:
        rows = section.get(name)
        if rows is None:
            tables.append(None)
            continue
        try:
            arr = np.asarray(rows, dtype=float)
            tables.append(DriveTable(arr[:, 0], arr[:, 1]))
        except (ValueError, IndexError) as exc:
            raise ConfigError(f"compensation.{name}", str(exc).split(": ", 1)[-1]) from None
    return Compensation(tuple(tables))


def comp_file_text(table: DriveTable, unit_m: float = 1.0) -> str:
    """A LinuxCNC comp file (COMP_FILE_TYPE 1) of ``table`` in machine units of ``unit_m``."""
    return "".join(f"{p / unit_m:.6f} {c / unit_m:.9f} {c / unit_m:.9f}\n"
                   for p, c in zip(table.positions, table.corrections))


def read_comp_file(text: str, unit_m: float = 1.0) -> DriveTable:
    """The table of a LinuxCNC comp file's text (COMP_FILE_TYPE 1; the forward trim)."""
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words or words[0].startswith(("#", ";")):
            continue
        if len(words) != 3:
            raise ConfigError("comp_file", f"line {number}: expected 'nominal forward-trim reverse-trim', got {line!r}")
        rows.append([float(words[0]) * unit_m, float(words[1]) * unit_m])
    arr = np.asarray(rows, dtype=float).reshape(-1, 2)
    return DriveTable(arr[:, 0], arr[:, 1])
