"""Messages <-> arrays: stamps, poses, joint states, machine poses, diagnostics.

Conventions (docs/architecture.md): SI units, REP-103 frames, quaternions (x, y, z, w)
as in geometry_msgs. Stamps are handled as integer nanoseconds in the cores (exact,
no float rounding of 1-2 kHz steps) and as builtin_interfaces/Time in messages.
Bad input raises ValueError naming the message field.
"""

from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseStamped, Transform, Twist
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from pkm_kinematics.task_space import TASK_SPACES, TaskSpace, motion_fields, pose_fields, task_pose, tool_pose

NS_PER_S = 1_000_000_000
QUATERNION_NORM_TOL = 1e-6
MACHINE_KINDS = ('planar', 'translational', 'struts')
_LEVELS = {0: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, 2: DiagnosticStatus.ERROR,
           3: DiagnosticStatus.STALE}


# ------------------------------------------------------------------- stamps
def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds (>= 0) -> builtin_interfaces/Time."""
    if isinstance(ns, bool) or not isinstance(ns, (int, np.integer)):
        raise ValueError(f'stamp: expected integer nanoseconds, got {ns!r}')
    ns = int(ns)
    if ns < 0 or ns >= (2**31) * NS_PER_S:
        raise ValueError(f'stamp: must be in [0, 2^31 s) as nanoseconds, got {ns}')
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


def stamp_to_ns(stamp: Time) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def _stamp(stamp) -> Time:
    """A builtin_interfaces/Time, an rclpy.time.Time or integer nanoseconds -> Time."""
    if isinstance(stamp, Time):
        return stamp
    if hasattr(stamp, 'nanoseconds'):
        return ns_to_stamp(stamp.nanoseconds)
    return ns_to_stamp(stamp)


# -------------------------------------------------------------------- poses
# Per-message paths (1-2 kHz): quaternion <-> matrix on Python floats, ~3x faster than
# the numpy helpers of pkm_kinematics.rotations for one 3 x 3 matrix.
def _quaternion(r) -> tuple:
    """Unit quaternion (x, y, z, w), w >= 0, of a row-major 9-tuple (Shepperd's method)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = ((r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, 0.25 * s)
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        q = (0.25 * s, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s)
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        q = ((r01 + r10) / s, 0.25 * s, (r12 + r21) / s, (r02 - r20) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        q = ((r02 + r20) / s, (r12 + r21) / s, 0.25 * s, (r10 - r01) / s)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[3] < 0.0:
        n = -n
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def pose_components(position, rotation) -> tuple[tuple, tuple]:
    """((x, y, z), (qx, qy, qz, qw)) of a position (3,) and a rotation matrix (3, 3),
    as Python floats, w >= 0 (the fields of a geometry_msgs/Pose). A non-finite input
    raises ValueError (a NaN pose is never published)."""
    try:
        px, py, pz = (position.tolist() if isinstance(position, np.ndarray) else position)
        px, py, pz = float(px), float(py), float(pz)
    except (TypeError, ValueError):
        raise ValueError(f'position: expected 3 numbers, got {position!r}') from None
    try:
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = (
            rotation.tolist() if isinstance(rotation, np.ndarray) else rotation)
        r = (float(r00), float(r01), float(r02), float(r10), float(r11), float(r12),
             float(r20), float(r21), float(r22))
    except (TypeError, ValueError):
        raise ValueError(f'rotation: expected a 3 x 3 matrix, got {rotation!r}') from None
    if not math.isfinite(px + py + pz + r[0] + r[1] + r[2] + r[3] + r[4] + r[5] + r[6] + r[7] + r[8]):
        raise ValueError(f'pose: contains NaN or infinite values: position {[px, py, pz]}, '
                         f'rotation {list(r)}')
    return (px, py, pz), _quaternion(r)


def pose_msg(position, rotation, stamp, frame_id: str, out: PoseStamped | None = None) -> PoseStamped:
    """PoseStamped from a position (3,) and a rotation matrix (3, 3).

    ``stamp`` is a builtin_interfaces/Time, an rclpy Time or integer nanoseconds. The
    quaternion has w >= 0. A non-finite input raises ValueError (a NaN pose is never
    published). ``out``: a message to fill and return instead of a new one.
    """
    (px, py, pz), (qx, qy, qz, qw) = pose_components(position, rotation)
    msg = PoseStamped() if out is None else out
    msg.header.stamp = _stamp(stamp)
    msg.header.frame_id = frame_id
    pos, ori = msg.pose.position, msg.pose.orientation
    pos.x, pos.y, pos.z = px, py, pz
    ori.x, ori.y, ori.z, ori.w = qx, qy, qz, qw
    return msg


def pose_from_msg(msg: PoseStamped) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of a PoseStamped; see :func:`pose_from_components`."""
    pos, ori = msg.pose.position, msg.pose.orientation
    return pose_from_components((pos.x, pos.y, pos.z), (ori.x, ori.y, ori.z, ori.w))


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
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    rot = [[1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
           [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
           [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)]]
    return np.array(p), np.array(rot)


# ------------------------------------------------------------- joint states
def joint_state_msg(names, stamp, position=None, velocity=None, effort=None,
                    frame_id: str = '', out: JointState | None = None) -> JointState:
    """JointState with ``names``; each given array must have one value per name.
    ``out``: a message to fill and return (its name list is replaced only if it differs)."""
    names = [str(n) for n in names]
    msg = JointState() if out is None else out
    msg.header.stamp = _stamp(stamp)
    msg.header.frame_id = frame_id
    if out is None or list(msg.name) != names:
        msg.name = names
    for field, values in (('position', position), ('velocity', velocity), ('effort', effort)):
        if values is None:
            continue
        values = [float(v) for v in (values.tolist() if isinstance(values, np.ndarray) else values)]
        if len(values) != len(names):
            raise ValueError(f'{field}: expected {len(names)} values (one per name), got {len(values)}')
        setattr(msg, field, values)
    return msg


# ------------------------------------------------------------- trajectories
def trajectory_msg(space, time_s, position, velocity, acceleration) -> MultiDOFJointTrajectory:
    """A sampled task-space trajectory (times (N,), poses, rates, accelerations (N, dof)
    in the coordinates of ``space``, pkm_kinematics.task_space) as the one-joint "tool"
    MultiDOFJointTrajectory that trajectory_node publishes: each point's pose, twist and
    twist rate in the base frame (task_space.motion_fields); header left to the caller."""
    msg = MultiDOFJointTrajectory(joint_names=["tool"])
    for t, x, v, a in zip(np.asarray(time_s, dtype=float).tolist(), np.asarray(position).tolist(),
                          np.asarray(velocity).tolist(), np.asarray(acceleration).tolist()):
        tf, vel, acc = Transform(), Twist(), Twist()
        p, q, lin, ang, lin_acc, ang_acc = motion_fields(space, x, v, a)
        tf.translation.x, tf.translation.y, tf.translation.z = p
        tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = q
        vel.linear.x, vel.linear.y, vel.linear.z = lin
        vel.angular.x, vel.angular.y, vel.angular.z = ang
        acc.linear.x, acc.linear.y, acc.linear.z = lin_acc
        acc.angular.x, acc.angular.y, acc.angular.z = ang_acc
        sec, nsec = divmod(round(t * 1e9), 1_000_000_000)
        msg.points.append(MultiDOFJointTrajectoryPoint(
            transforms=[tf], velocities=[vel], accelerations=[acc],
            time_from_start=Duration(sec=int(sec), nanosec=int(nsec))))
    return msg


# ------------------------------------------------------ machine <-> tool pose
# The task space's own formulas (pkm_kinematics.task_space), with the checks of a
# message boundary: a machine's model names its task space (``model.task_space``).
def _check_space(space) -> None:
    if not isinstance(space, TaskSpace):
        raise ValueError(f'space: must be a task space (one of {sorted(TASK_SPACES)}), got {space!r}')


def machine_to_tool_pose(space: TaskSpace, x) -> tuple[np.ndarray, np.ndarray]:
    """Machine pose -> tool pose in world (docs/architecture.md, mounting;
    ``task_space.tool_pose``): planar (x, y, theta) -> ((x, y, 0), Rz(theta)); position
    p -> (p, I); spatial (x, y, z, a, b, c) -> (p, Rz(c) Ry(b) Rx(a))."""
    _check_space(space)
    x = np.asarray(x, dtype=float)
    if x.shape != (space.dof,) or not np.isfinite(x).all():
        raise ValueError(f'x: expected {space.dof} finite numbers ({space.describe()}), got {x.tolist()}')
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
        raise ValueError(f'reference_theta: must be finite, got {reference_theta!r}')
    return task_pose(space, p, rot, None if reference_theta is None else float(reference_theta))


# -------------------------------------------------------------- diagnostics
def _format(value) -> str:
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def diagnostic_status(name: str, level, message: str, values: dict | None = None,
                      hardware_id: str = '') -> DiagnosticStatus:
    """DiagnosticStatus; ``level`` 0-3 (OK, WARN, ERROR, STALE) or the message's bytes
    constant; ``values`` become KeyValues, floats with repr (round-trips exactly)."""
    if isinstance(level, (bytes, bytearray)):
        level = int.from_bytes(level, 'little')
    if level not in _LEVELS:
        raise ValueError(f'level: must be 0 (OK), 1 (WARN), 2 (ERROR) or 3 (STALE), got {level!r}')
    status = DiagnosticStatus()
    status.level = _LEVELS[level]
    status.name = name
    status.message = message
    status.hardware_id = hardware_id
    status.values = [KeyValue(key=str(k), value=_format(v)) for k, v in (values or {}).items()]
    return status


def diagnostic_array(stamp, statuses) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = _stamp(stamp)
    msg.status = list(statuses)
    return msg


def line_list_markers(segments, stamp, frame_id: str = "world", ns: str = "legs") -> MarkerArray:
    """One LINE_LIST marker (1 cm wide, blue) of the segments (pairs of 3-D points),
    e.g. the legs of a machine (pkm_sim_hw.plant.leg_segments), for RViz."""
    marker = Marker(type=Marker.LINE_LIST, action=Marker.ADD, ns=ns, id=0)
    marker.header.frame_id = frame_id
    marker.header.stamp = _stamp(stamp)
    marker.scale.x = 0.01
    marker.color.r, marker.color.g, marker.color.b, marker.color.a = 0.2, 0.5, 0.9, 1.0
    marker.pose.orientation.w = 1.0
    for a, b in segments:
        marker.points += [Point(x=a[0], y=a[1], z=a[2]), Point(x=b[0], y=b[1], z=b[2])]
    return MarkerArray(markers=[marker])


UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"     # an endpoint discovered before its node's name


def graph_senders(node, topic_name: str) -> list[str]:
    """The node names publishing the resolved ``topic_name`` as ``node`` sees the graph
    (sources.AllowedSenders.check's argument); a graph that cannot be asked answers a
    name no run allows (the check fails closed)."""
    try:
        infos = node.get_publishers_info_by_topic(topic_name)
    except Exception as exc:                # noqa: BLE001 - rclpy's RCLError on a closing context
        return [f"<the graph could not be asked: {type(exc).__name__}>"]
    return publisher_names(infos)


def publisher_names(infos) -> list[str]:
    """Full node names (``/ns/name``) of ``get_publishers_info_by_topic``'s entries, one
    per publisher (a node with two publishers is named twice); endpoints whose node is
    not discovered yet are left out."""
    return [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos if i.node_name != UNKNOWN_NODE]


def signed_message(signer, topic: str, msg) -> bytes:
    """A stamped command (goal, trajectory, load) serialized with its credential in
    ``header.frame_id`` (pkm_common.credential); ``signer`` None: serialized as is."""
    from rclpy.serialization import serialize_message
    if signer is None:
        return serialize_message(msg)
    msg.header.frame_id = signer.placeholder()
    return signer.seal(topic, serialize_message(msg), stamped=True)
