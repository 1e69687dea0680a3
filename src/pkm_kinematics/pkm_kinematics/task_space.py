"""The task coordinates a machine controls, written once: their names, which of them
are a translation, and the G-code word of each (``TaskSpace``). Every model names
its own (``machine.task_space``); the G-code reader, the planner and the panel take
it from there instead of asking what kind of machine they were given.

========  ==========================  ===========  ===============
name      coordinates                 translation  G-code words
========  ==========================  ===========  ===============
planar    x, y, theta (SE(2))         x, y         X Y C
position  x, y, z                     x, y, z      X Y Z
spatial   x, y, z, a, b, c (SE(3))    x, y, z      X Y Z A B C
========  ==========================  ===========  ===============

Angles in radians; a, b, c are the roll-pitch-yaw angles of ``rotations.rotation_from_rpy``
(R = Rz(c) Ry(b) Rx(a), LinuxCNC genhexkins' A B C), theta the rotation about z. A
G-code program gives angles in degrees (``pkm_trajectory.gcode``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TaskSpace:
    name: str
    axes: tuple            # the coordinates' names, in order
    translation_axes: int  # how many leading coordinates are a translation (m); the rest are angles (rad)
    words: tuple           # the G-code word of each coordinate

    @property
    def dof(self) -> int:
        return len(self.axes)

    def describe(self) -> str:
        """'x, y, theta' for messages."""
        return ", ".join(self.axes)


PLANAR = TaskSpace("planar", ("x", "y", "theta"), 2, ("X", "Y", "C"))
POSITION = TaskSpace("position", ("x", "y", "z"), 3, ("X", "Y", "Z"))
SPATIAL = TaskSpace("spatial", ("x", "y", "z", "a", "b", "c"), 3, ("X", "Y", "Z", "A", "B", "C"))
TASK_SPACES = {space.name: space for space in (PLANAR, POSITION, SPATIAL)}

__all__ = ["PLANAR", "POSITION", "SPATIAL", "TASK_SPACES", "TaskSpace"]
