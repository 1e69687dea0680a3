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

from .rotations import (angular_motion_floats, quaternion_from_rotation_floats, rate_matrix, rate_matrix_derivative,
                        rate_matrix_derivative_kernel, rate_matrix_kernel, rotation_about_z, rotation_from_rpy,
                        rpy_from_rotation, rpy_rotation_floats, unwrap_to)


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



def tool_pose(space: TaskSpace, x) -> tuple[np.ndarray, np.ndarray]:
    """The tool's pose in the world of a task-space pose: (position (3,), rotation
    (3, 3)). planar (x, y, theta) -> ((x, y, 0), Rz(theta)); position p -> (p, I);
    spatial (x, y, z, a, b, c) -> (p, Rz(c) Ry(b) Rx(a))."""
    if space is PLANAR:
        return np.array([x[0], x[1], 0.0]), rotation_about_z(float(x[2]))
    if space is POSITION:
        return np.array(x[:3], dtype=float), np.eye(3)
    return np.array(x[:3], dtype=float), rotation_from_rpy(*x[3:6])


def pose_fields(space: TaskSpace, x) -> tuple[tuple, tuple]:
    """:func:`tool_pose` as the fields of a pose message, per step: (position (3),
    quaternion (x, y, z, w)), numbers as given (floats, or numpy scalars)."""
    if space is PLANAR:
        half = 0.5 * x[2]
        return (x[0], x[1], 0.0), (0.0, 0.0, math.sin(half), math.cos(half))
    if space is POSITION:
        return (x[0], x[1], x[2]), (0.0, 0.0, 0.0, 1.0)
    return (x[0], x[1], x[2]), tuple(quaternion_from_rotation_floats(rpy_rotation_floats(x[3], x[4], x[5])).tolist())


def task_pose(space: TaskSpace, position, rotation, reference_angle: float | None = None) -> np.ndarray:
    """The inverse of :func:`tool_pose`. planar: (x, y, yaw), the yaw put on the
    revolution of ``reference_angle`` (a planar machine's rotation is unlimited: ARCHI's
    nacelle turns any number of times); height, roll and pitch are dropped. position:
    the position. spatial: the position and the roll, pitch and yaw."""
    p = np.asarray(position, dtype=float)
    if space is POSITION:
        return p.copy()
    if space is SPATIAL:
        return np.concatenate((p, rpy_from_rotation(np.asarray(rotation, dtype=float))))
    theta = math.atan2(rotation[1][0], rotation[0][0])
    if reference_angle is not None:
        theta = unwrap_to(theta, reference_angle)
    return np.array([p[0], p[1], theta])


def load_components(space: TaskSpace, force, moment) -> list:
    """A wrench (force, moment: 3 each, world frame) in the components of an external
    load in this task space (``space.loads``): fx, fy, mz on a planar machine, fx, fy,
    fz on a position one, all six on a spatial one."""
    wrench = {"fx": force[0], "fy": force[1], "fz": force[2], "mx": moment[0], "my": moment[1], "mz": moment[2]}
    return [wrench[label] for label in space.loads]


def motion_fields(space: TaskSpace, x, v, a) -> tuple:
    """A task-space sample (pose x, rates v, accelerations a) as the fields of a
    trajectory point in the base frame: (translation (3), quaternion (x, y, z, w),
    linear velocity, angular velocity, linear acceleration, angular acceleration).
    planar: the yaw theta about z; position: no rotation; spatial: R = Rz(c) Ry(b)
    Rx(a), w = E (a', b', c'), w' = E (a'', b'', c'') + E' (a', b', c')
    (rotations.rate_matrix)."""
    position, quaternion = pose_fields(space, x)
    if space is PLANAR:
        return (position, quaternion, (v[0], v[1], 0.0), (0.0, 0.0, v[2]), (a[0], a[1], 0.0), (0.0, 0.0, a[2]))
    if space is POSITION:
        return (position, quaternion, (v[0], v[1], v[2]), (0.0, 0.0, 0.0), (a[0], a[1], a[2]), (0.0, 0.0, 0.0))
    omega, alpha = angular_motion(x[3:6], v[3:6], a[3:6])
    return (position, quaternion, tuple(v[:3]), tuple(omega.tolist()), tuple(a[:3]), tuple(alpha.tolist()))


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


def angle_rates_batch(angles, omega, alpha) -> tuple[np.ndarray, np.ndarray]:
    """:func:`angle_rates` of N samples at once (arrays (N, 3)), the same numbers bit
    for bit (the same rate matrices, LAPACK's solve and the matrix products per
    sample, batched): a spatial trajectory's rates read back in ~1/3 of the time."""
    angles, omega, alpha = (np.asarray(v, dtype=float).reshape(-1, 3) for v in (angles, omega, alpha))
    rate = np.array([rate_matrix_kernel.py_func(b, c) for b, c in angles[:, 1:].tolist()]).reshape(-1, 3, 3)
    rates = np.linalg.solve(rate, omega[..., None])[..., 0]
    derivative = np.array([rate_matrix_derivative_kernel.py_func(b, c, rb, rc) for (b, c), (rb, rc) in
                           zip(angles[:, 1:].tolist(), rates[:, 1:].tolist())]).reshape(-1, 3, 3)
    accelerations = np.linalg.solve(rate, (alpha - (derivative @ rates[..., None])[..., 0])[..., None])[..., 0]
    return rates, accelerations


__all__ = ["PLANAR", "POSITION", "SPATIAL", "TASK_SPACES", "TaskSpace", "angle_rates", "angle_rates_batch",
           "angular_motion",
           "load_components", "motion_fields", "pose_fields", "task_pose", "task_twists", "tool_pose"]
