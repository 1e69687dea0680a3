"""Poses as the fields of a message, without messages (pure: no rclpy): a position and
a rotation <-> (x, y, z), (qx, qy, qz, qw); a machine's pose <-> the tool's pose in
world, with the checks of a message boundary. :mod:`pkm_common.conversions` builds the
messages from these; the sans-IO loops and the panel's core use them directly.

Conventions (docs/architecture.md): SI units, REP-103 frames, quaternions (x, y, z, w)
as in geometry_msgs. Bad input raises ValueError naming the field.
"""

from __future__ import annotations

import math

import numpy as np

from pkm_kinematics.errors import FieldError
from pkm_kinematics.rotations import rotation_quaternion_floats, unit_quaternion_rotation_floats
from pkm_kinematics.task_space import TASK_SPACES, TaskSpace, pose_fields, task_pose, tool_pose

QUATERNION_NORM_TOL = 1e-6
MACHINE_KINDS = ('planar', 'translational', 'struts')


# Per-message paths (1-2 kHz): quaternion <-> matrix on Python floats, ~3x faster than
# the numpy helpers of pkm_kinematics.rotations for one 3 x 3 matrix (the same formulas
# compiled: rotations' *_kernel, for the Gough sensor's reading kernel).
_quaternion = rotation_quaternion_floats


def pose_components(position, rotation) -> tuple[tuple, tuple]:
    """((x, y, z), (qx, qy, qz, qw)) of a position (3,) and a rotation matrix (3, 3),
    as Python floats, w >= 0 (the fields of a geometry_msgs/Pose). A non-finite input
    raises ValueError (a NaN pose is never published)."""
    try:
        px, py, pz = (position.tolist() if isinstance(position, np.ndarray) else position)
        px, py, pz = float(px), float(py), float(pz)
    except (TypeError, ValueError):
        raise FieldError('position', f'expected 3 numbers, got {position!r}') from None
    try:
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = (
            rotation.tolist() if isinstance(rotation, np.ndarray) else rotation)
        r = (float(r00), float(r01), float(r02), float(r10), float(r11), float(r12),
             float(r20), float(r21), float(r22))
    except (TypeError, ValueError):
        raise FieldError('rotation', f'expected a 3 x 3 matrix, got {rotation!r}') from None
    if not math.isfinite(px + py + pz + r[0] + r[1] + r[2] + r[3] + r[4] + r[5] + r[6] + r[7] + r[8]):
        raise FieldError('pose', f'contains NaN or infinite values: position {[px, py, pz]}, '
                                 f'rotation {list(r)}')
    return (px, py, pz), _quaternion(r)


def pose_from_components(position, orientation) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of a pose's fields (x, y, z), (qx, qy, qz, qw)
    (a message, or pkm_common.cdr.PoseStampedData read from its bytes).

    Raises ValueError naming the field for NaN/inf components and for a quaternion
    whose norm differs from 1 by more than 1e-6 (a malformed message, not rounding);
    within that tolerance the quaternion is normalised.
    """
    p = tuple(position)
    x, y, z, w = q = tuple(orientation)
    if not math.isfinite(p[0] + p[1] + p[2]):
        bad = [f'pose.position.{c}' for c, v in zip('xyz', p) if not math.isfinite(v)]
        raise ValueError(f'{", ".join(bad) or "pose.position"}: must be finite, got {list(p)}')
    if not math.isfinite(x + y + z + w):
        bad = [f'pose.orientation.{c}' for c, v in zip('xyzw', q) if not math.isfinite(v)]
        raise ValueError(f'{", ".join(bad) or "pose.orientation"}: must be finite, got {list(q)}')
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > QUATERNION_NORM_TOL:
        raise ValueError(f'pose.orientation: must be a unit quaternion (|q| within 1 +- '
                         f'{QUATERNION_NORM_TOL:g}), got |q| = {norm!r}')
    rot = unit_quaternion_rotation_floats(x / norm, y / norm, z / norm, w / norm)
    return np.array(p), np.array(rot).reshape(3, 3)


# ------------------------------------------------------ machine <-> tool pose
# The task space's own formulas (pkm_kinematics.task_space), with the checks of a
# message boundary: a machine's model names its task space (``model.task_space``).
def _check_space(space) -> None:
    if not isinstance(space, TaskSpace):
        raise FieldError('space', f'must be a task space (one of {sorted(TASK_SPACES)}), got {space!r}')


def machine_to_tool_pose(space: TaskSpace, x) -> tuple[np.ndarray, np.ndarray]:
    """Machine pose -> tool pose in world (docs/architecture.md, Conventions;
    ``task_space.tool_pose``): planar (x, y, theta) -> ((x, y, 0), Rz(theta)); position
    p -> (p, I); spatial (x, y, z, a, b, c) -> (p, Rz(c) Ry(b) Rx(a))."""
    _check_space(space)
    x = np.asarray(x, dtype=float)
    if x.shape != (space.dof,) or not np.isfinite(x).all():
        raise FieldError('x', f'expected {space.dof} finite numbers ({space.describe()}), got {x.tolist()}')
    return tool_pose(space, x)


def machine_pose_components(space: TaskSpace, x) -> tuple[tuple, tuple]:
    """Machine pose -> (position (3,), orientation quaternion (x, y, z, w)) as numbers
    for a PoseStamped (floats, or the input's numpy scalars): the per-step form of
    :func:`machine_to_tool_pose`, without its checks (``task_space.pose_fields``)."""
    return pose_fields(space, x)


def tool_pose_to_machine(space: TaskSpace, position, rotation, reference_theta: float | None = None) -> np.ndarray:
    """Tool pose in world -> machine pose; inverse of :func:`machine_to_tool_pose`
    (``task_space.task_pose``): a planar machine's yaw on the revolution of
    ``reference_theta``, its height, roll and pitch dropped."""
    _check_space(space)
    p = np.asarray(position, dtype=float)
    rot = np.asarray(rotation, dtype=float)
    if p.shape != (3,) or rot.shape != (3, 3) or not (np.isfinite(p).all() and np.isfinite(rot).all()):
        raise ValueError(f'tool pose: expected a finite position (3,) and rotation (3, 3), '
                         f'got {p.tolist()}, {rot.tolist()}')
    if reference_theta is not None and not math.isfinite(float(reference_theta)):
        raise FieldError('reference_theta', f'must be finite, got {reference_theta!r}')
    return task_pose(space, p, rot, None if reference_theta is None else float(reference_theta))
