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

import math
from dataclasses import dataclass

import numpy as np

from .rotations import (angular_motion_floats, quaternion_from_rotation, rate_matrix, rate_matrix_derivative,
                        rotation_from_rpy)


@dataclass(frozen=True)
class TaskSpace:
    name: str
    axes: tuple            # the coordinates' names, in order
    translation_axes: int  # how many leading coordinates are a translation (m); the rest are angles (rad)
    words: tuple           # the G-code word of each coordinate
    loads: tuple           # the components of an external load in these coordinates (f: N, m: N m)

    @property
    def dof(self) -> int:
        return len(self.axes)

    def describe(self) -> str:
        """'x, y, theta' for messages."""
        return ", ".join(self.axes)


PLANAR = TaskSpace("planar", ("x", "y", "theta"), 2, ("X", "Y", "C"), ("fx", "fy", "mz"))
POSITION = TaskSpace("position", ("x", "y", "z"), 3, ("X", "Y", "Z"), ("fx", "fy", "fz"))
SPATIAL = TaskSpace("spatial", ("x", "y", "z", "a", "b", "c"), 3, ("X", "Y", "Z", "A", "B", "C"),
                    ("fx", "fy", "fz", "mx", "my", "mz"))
TASK_SPACES = {space.name: space for space in (PLANAR, POSITION, SPATIAL)}



def motion_fields(space: TaskSpace, x, v, a) -> tuple:
    """A task-space sample (pose x, rates v, accelerations a) as the fields of a
    trajectory point in the base frame: (translation (3), quaternion (x, y, z, w),
    linear velocity, angular velocity, linear acceleration, angular acceleration).
    planar: the yaw theta about z; position: no rotation; spatial: R = Rz(c) Ry(b)
    Rx(a), w = E (a', b', c'), w' = E (a'', b'', c'') + E' (a', b', c')
    (rotations.rate_matrix)."""
    if space is PLANAR:
        return ((x[0], x[1], 0.0), (0.0, 0.0, math.sin(0.5 * x[2]), math.cos(0.5 * x[2])),
                (v[0], v[1], 0.0), (0.0, 0.0, v[2]), (a[0], a[1], 0.0), (0.0, 0.0, a[2]))
    if space is POSITION:
        return ((x[0], x[1], x[2]), (0.0, 0.0, 0.0, 1.0), (v[0], v[1], v[2]), (0.0, 0.0, 0.0),
                (a[0], a[1], a[2]), (0.0, 0.0, 0.0))
    omega, alpha = angular_motion(x[3:6], v[3:6], a[3:6])
    q = quaternion_from_rotation(rotation_from_rpy(x[3], x[4], x[5]))
    return (tuple(x[:3]), tuple(q.tolist()), tuple(v[:3]), tuple(omega.tolist()), tuple(a[:3]),
            tuple(alpha.tolist()))


def angular_motion(angles, rates, accelerations) -> tuple[np.ndarray, np.ndarray]:
    """The angular velocity and acceleration (base frame) of roll-pitch-yaw angles
    moving at ``rates`` with ``accelerations``: w = E (a', b', c'),
    w' = E (a'', b'', c'') + E' (a', b', c') (``rotations.rate_matrix``)."""
    motion = angular_motion_floats(float(angles[1]), float(angles[2]), *(float(v) for v in rates),
                                   *(float(v) for v in accelerations))
    return np.array(motion[:3]), np.array(motion[3:])


def task_twists(space: TaskSpace, x, v, a) -> tuple[list, list]:
    """The velocity and acceleration of a task-space sample as the controller and the
    dynamic models take them: the rates themselves for planar and position machines
    (their dynamics are written in those coordinates); for a spatial pose the twist
    (v, w) and its rate (v', w'), w in the base frame (``angular_motion``)."""
    if space is not SPATIAL:
        return list(v), list(a)
    w = angular_motion_floats(x[4], x[5], v[3], v[4], v[5], a[3], a[4], a[5])
    return [v[0], v[1], v[2], w[0], w[1], w[2]], [a[0], a[1], a[2], w[3], w[4], w[5]]


def angle_rates(angles, omega, alpha) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`motion_fields`' rotation part: (a', b', c') and
    (a'', b'', c'') of the angular velocity ``omega`` and acceleration ``alpha`` at
    the angles (a, b, c) (|b| < pi/2)."""
    _, b, c = angles
    rate = rate_matrix(*angles)
    rates = np.linalg.solve(rate, np.asarray(omega, dtype=float))
    accelerations = np.linalg.solve(rate, np.asarray(alpha, dtype=float)
                                    - rate_matrix_derivative(b, c, rates[1], rates[2]) @ rates)
    return rates, accelerations


__all__ = ["PLANAR", "POSITION", "SPATIAL", "TASK_SPACES", "TaskSpace", "angle_rates", "angular_motion", "motion_fields",
           "task_twists"]
