"""Messages <-> arrays: stamps, poses, joint states, trajectories, diagnostics (the
fields of a pose without a message: :mod:`pkm_common.poses`).

Conventions (docs/architecture.md): SI units, REP-103 frames, quaternions (x, y, z, w)
as in geometry_msgs. Stamps are handled as integer nanoseconds in the cores (exact,
no float rounding of 1-2 kHz steps) and as builtin_interfaces/Time in messages.
Bad input raises ValueError naming the message field.
"""

from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseStamped, Transform, Twist
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from pkm_common.cdr import encode_diagnostic_array, encode_multidof_trajectory
from pkm_common.poses import pose_components, pose_from_components
from pkm_kinematics.errors import FieldError
from pkm_kinematics.task_space import motion_fields

NS_PER_S = 1_000_000_000
_LEVELS = {0: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, 2: DiagnosticStatus.ERROR,
           3: DiagnosticStatus.STALE}


# ------------------------------------------------------------------- stamps
def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds (>= 0) -> builtin_interfaces/Time."""
    if isinstance(ns, bool) or not isinstance(ns, (int, np.integer)):
        raise FieldError('stamp', f'expected integer nanoseconds, got {ns!r}')
    ns = int(ns)
    if ns < 0 or ns >= (2**31) * NS_PER_S:
        raise FieldError('stamp', f'must be in [0, 2^31 s) as nanoseconds, got {ns}')
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


def trajectory_fields(space, position, velocity, acceleration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each sample's fields of a trajectory point in the base frame, per point
    (task_space.motion_fields, as :func:`trajectory_msg` has them): transforms (N, 7:
    translation, quaternion x y z w), velocity and acceleration twists (N, 6 each)."""
    fields = [motion_fields(space, x, v, a) for x, v, a in zip(np.asarray(position).tolist(),
                                                                np.asarray(velocity).tolist(),
                                                                np.asarray(acceleration).tolist())]
    return (np.array([(*p, *q) for p, q, *_ in fields], dtype=float).reshape(-1, 7),
            np.array([(*lin, *ang) for _, _, lin, ang, _, _ in fields], dtype=float).reshape(-1, 6),
            np.array([(*lin, *ang) for *_, lin, ang in fields], dtype=float).reshape(-1, 6))


def trajectory_bytes(space, time_s, position, velocity, acceleration, stamp_ns: int, signer=None,
                     frame_id: str = "world", fields=None) -> bytes:
    """:func:`trajectory_msg` serialized, with ``stamp_ns`` in its header and signed by
    ``signer`` (pkm_common.credential: the tag in ``header.frame_id``, as
    ``signed_message`` signs a message; None: ``frame_id``): the points' fields
    (:func:`trajectory_fields`, or ``fields`` made before) as one record array
    (cdr.encode_multidof_trajectory): 1.8 s -> ~0.4 s for a calibration program of 42 000 points."""
    transforms, velocities, accelerations = fields or trajectory_fields(space, position, velocity, acceleration)
    frame = frame_id if signer is None else signer.placeholder()
    data = encode_multidof_trajectory(stamp_ns, frame, "tool", time_s, transforms, velocities, accelerations)
    return data if signer is None else signer.seal("trajectory", data, stamped=True)


# -------------------------------------------------------------- diagnostics
def _format(value) -> str:
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def _level(level) -> bytes:
    """A diagnostic level 0-3 (or its byte) as the message's byte; FieldError otherwise."""
    if isinstance(level, (bytes, bytearray)):
        level = int.from_bytes(level, 'little')
    if level not in _LEVELS:
        raise FieldError('level', f'must be 0 (OK), 1 (WARN), 2 (ERROR) or 3 (STALE), got {level!r}')
    return _LEVELS[level]


def diagnostic_status(name: str, level, message: str, values: dict | None = None,
                      hardware_id: str = '') -> DiagnosticStatus:
    """DiagnosticStatus; ``level`` 0-3 (OK, WARN, ERROR, STALE) or the message's bytes
    constant; ``values`` become KeyValues, floats with repr (round-trips exactly)."""
    status = DiagnosticStatus()
    status.level = _level(level)
    status.name = name
    status.message = message
    status.hardware_id = hardware_id
    status.values = [KeyValue(key=str(k), value=_format(v)) for k, v in (values or {}).items()]
    return status


def diagnostic_bytes(stamp_ns: int, name: str, level, message: str, values: dict | None = None,
                     hardware_id: str = '') -> bytes:
    """``diagnostic_array`` of one ``diagnostic_status`` serialized (the same bytes as
    rclpy's, cdr.encode_diagnostic_array), without the message objects."""
    pairs = [(str(k), _format(v)) for k, v in (values or {}).items()]
    return encode_diagnostic_array(stamp_ns, [(_level(level)[0], name, message, hardware_id, pairs)])


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
