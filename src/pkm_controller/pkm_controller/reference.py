"""The reference the controller tracks: a sampled task-space trajectory (pure core).

A trajectory is what ``pkm_trajectory`` plans and ``trajectory_node`` publishes:
times, positions, velocities and accelerations in task coordinates (planar
(x, y, theta), a position (x, y, z), or a spatial pose (x, y, z, a, b, c):
pkm_kinematics.task_space). Between samples the reference is linearly
interpolated; before the start it is the first sample, after the end the last one at
rest (the machine holds the end pose). Sampling runs every control cycle, so it is
a bisection plus a few float operations (~2 us).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from pkm_common.cdr import TrajectoryData
from pkm_kinematics.errors import FieldError
from pkm_kinematics.jit import direct_call, kernel
from pkm_kinematics.rotations import rotation_from_quaternion, rpy_from_rotation, unwrap_to, yaw_of_quaternion
from pkm_kinematics.task_space import PLANAR, SPATIAL, TaskSpace, angle_rates_batch


class Reference:
    """x_d(t), v_d(t), a_d(t) of a sampled trajectory, t relative to its start (s)."""

    def __init__(self, time_s, position, velocity=None, acceleration=None):
        t = np.asarray(time_s, dtype=float)
        x = np.asarray(position, dtype=float)
        self.stamp_ns = None           # the trajectory message's header stamp, when it came as one
        if t.ndim != 1 or t.size < 1 or x.ndim != 2 or x.shape[0] != t.size or x.shape[1] not in (3, 6):
            raise FieldError("trajectory", f"expected N times and N x 3 (or N x 6) positions, got shapes "
                                           f"{t.shape}, {x.shape}")
        v = np.zeros_like(x) if velocity is None else np.asarray(velocity, dtype=float)
        a = np.zeros_like(x) if acceleration is None else np.asarray(acceleration, dtype=float)
        if v.shape != x.shape or a.shape != x.shape:
            raise FieldError("trajectory", f"velocities and accelerations must be N x {x.shape[1]} like the "
                                           f"positions, got {v.shape}, {a.shape}")
        for name, arr in (("time_from_start", t), ("positions", x), ("velocities", v), ("accelerations", a)):
            if not np.isfinite(arr).all():
                raise FieldError("trajectory", f"{name} contain NaN or infinite values")
        if t.size > 1 and not (np.diff(t) > 0.0).all():
            k = int(np.argmax(np.diff(t) <= 0.0)) + 1
            raise FieldError("trajectory", f"time_from_start must increase strictly, point {k} is at "
                                           f"{t[k]:.9g} s after {t[k - 1]:.9g} s")
        if t[0] < 0.0:
            raise FieldError("trajectory", f"time_from_start must be >= 0, got {t[0]:.9g} s")
        # a row per sample, as sample_reference_kernel takes it; the columns as lists when
        # asked (a study's run took ~1 ms making lists of a 4,657-sample trajectory)
        self.table = np.column_stack((t, x, v, a)).astype(float)
        self._d = x.shape[1]

    @functools.cached_property
    def time_s(self) -> list:
        return self.table[:, 0].tolist()

    @functools.cached_property
    def position(self) -> list:
        return self.table[:, 1:1 + self._d].tolist()

    @functools.cached_property
    def velocity(self) -> list:
        return self.table[:, 1 + self._d:1 + 2 * self._d].tolist()

    @functools.cached_property
    def acceleration(self) -> list:
        return self.table[:, 1 + 2 * self._d:].tolist()

    @property
    def points(self) -> int:
        return len(self.table)

    @classmethod
    def hold(cls, pose) -> "Reference":
        """Stand still at ``pose``."""
        return cls([0.0], [list(pose)])

    @property
    def duration_s(self) -> float:
        return float(self.table[-1, 0])

    @property
    def start(self) -> list:
        return self.table[0, 1:1 + self._d].tolist()

    @property
    def end(self) -> list:
        return self.table[-1, 1:1 + self._d].tolist()

    def sample(self, t: float) -> tuple[list, list, list]:
        """(x_d, v_d, a_d) at ``t`` seconds after the start (:func:`sample_reference_kernel`)."""
        x, v, a = _sample(self.table, float(t))
        return x.tolist(), v.tolist(), a.tolist()


@kernel("(float64[:, :], float64)")
def sample_reference_kernel(table, t):
    """(x, v, a) of a sampled trajectory at ``t``: ``table`` a row per sample (time,
    then d positions, d velocities, d accelerations), linearly interpolated between
    samples; the first sample before the start, the last one at rest after the end."""
    m, d = table.shape[0], (table.shape[1] - 1) // 3
    x, v, a = np.empty(d), np.empty(d), np.empty(d)
    if t <= table[0, 0]:
        x[:], v[:], a[:] = table[0, 1:1 + d], table[0, 1 + d:1 + 2 * d], table[0, 1 + 2 * d:]
        return x, v, a
    if t >= table[m - 1, 0]:
        x[:] = table[m - 1, 1:1 + d]
        v[:] = 0.0
        a[:] = 0.0
        return x, v, a
    k = np.searchsorted(table[:, 0], t, side="right")
    t0, t1 = table[k - 1, 0], table[k, 0]
    w = (t - t0) / (t1 - t0)
    u = 1.0 - w
    for j in range(d):
        x[j] = u * table[k - 1, 1 + j] + w * table[k, 1 + j]
        v[j] = u * table[k - 1, 1 + d + j] + w * table[k, 1 + d + j]
        a[j] = u * table[k - 1, 1 + 2 * d + j] + w * table[k, 1 + 2 * d + j]
    return x, v, a


_sample = direct_call(sample_reference_kernel)     # Reference.sample makes each argument with its declared type


REST_TOLERANCE = 1e-3           # m/s (rad/s): "at rest" at a trajectory's ends
POSITION_TOLERANCE = 1e-5       # m (rad): a step's position against its velocities' trapezoid
VELOCITY_TOLERANCE = 1e-3       # m/s (rad/s): a step's velocity against its accelerations'
RELATIVE_TOLERANCE = 0.01       # ... plus this part of the step


def _near_steps(step: np.ndarray) -> np.ndarray:
    """|step| at each step or either neighbour, the largest (per axis)."""
    size = np.abs(step)
    out = size.copy()
    out[1:] = np.maximum(out[1:], size[:-1])
    out[:-1] = np.maximum(out[:-1], size[1:])
    return out


def check_consistent(reference: Reference) -> None:
    """A trajectory the controller can follow as it is: it starts and ends at rest (the
    controller takes one only while holding, and holds its end), and each step's
    position and velocity changes are the trapezoid integrals of its velocities and
    accelerations. The trapezoid is exact only for a rate linear over the step: where
    the jerk turns within a step it is off by up to J dt^2 / 4 (3.2e-3 rad/s at 250 Hz
    and 800 rad/s^3), so the tolerance grows with the rate's change over the step and
    its neighbours (dt |delta rate| / 2, J dt^2 / 2 there). The velocities and
    accelerations are the controller's feed-forward: a trajectory must carry them (one
    of positions alone is not a motion here). A bogus one (2 m/s from rest, positions
    that jump while the velocities say still) otherwise ran into a following-error or
    encoder trip that named something else. Raises ValueError naming the point and
    axis."""
    table = reference.table                  # the same floats as the lists, already an array
    d = (table.shape[1] - 1) // 3
    t, x, v, a = table[:, 0], table[:, 1:1 + d], table[:, 1 + d:1 + 2 * d], table[:, 1 + 2 * d:]
    for k, where in ((0, "starts"), (len(t) - 1, "ends")):
        i = int(np.argmax(np.abs(v[k])))
        if abs(v[k, i]) > REST_TOLERANCE:
            raise FieldError("trajectory", f"it {where} moving (point {k}, task axis {i} at {v[k, i]:.6g} per s); "
                                           f"a trajectory starts and ends at rest (within {REST_TOLERANCE:g})")
    if len(t) < 2:
        return
    dt = np.diff(t)[:, None]
    for name, values, rates, tolerance in (("position", x, v, POSITION_TOLERANCE),
                                           ("velocity", v, a, VELOCITY_TOLERANCE)):
        step = np.diff(values, axis=0)
        off = np.abs(step - 0.5 * (rates[1:] + rates[:-1]) * dt)
        bad = off > tolerance + RELATIVE_TOLERANCE * np.abs(step) + 0.5 * dt * _near_steps(np.diff(rates, axis=0))
        if bad.any():
            k, i = (int(n) for n in np.argwhere(bad)[0])
            given = 0.5 * (rates[k + 1, i] + rates[k, i]) * dt[k, 0]
            rates_name = "velocities" if name == "position" else "accelerations"
            raise FieldError("trajectory", f"point {k + 1} (t = {t[k + 1]:.4f} s), task axis {i}: its {name} "
                                           f"changes by {step[k, i]:.6g} where its {rates_name} give "
                                           f"{given:.6g}: not a motion")


def minimum_jerk(tau: float) -> tuple[float, float, float]:
    """(s, ds/dtau, d2s/dtau2) of the rest-to-rest quintic s = 10 tau^3 - 15 tau^4 +
    6 tau^5 on tau in [0, 1] (Flash and Hogan's minimum-jerk move): zero velocity and
    acceleration at both ends; peak ds/dtau 1.875 at tau = 1/2."""
    t2 = tau * tau
    return (t2 * tau * (10.0 + tau * (-15.0 + 6.0 * tau)), 30.0 * t2 * (1.0 - tau) ** 2,
            60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau))


PEAK_RATE = 1.875               # max ds/dtau of minimum_jerk
PEAK_CURVATURE = 10.0 / math.sqrt(3.0)      # max |d2s/dtau2| of minimum_jerk, at tau = (3 -+ sqrt 3) / 6


def approach_duration(distance_m: float, angle_rad: float, speed_m_s: float, speed_rad_s: float,
                      acceleration_m_s2: float, acceleration_rad_s2: float) -> float:
    """The shortest minimum-jerk move over ``distance_m`` and ``angle_rad`` within the
    peak speeds (PEAK_RATE d / T) and accelerations (PEAK_CURVATURE d / T^2)."""
    return max(PEAK_RATE * distance_m / speed_m_s, PEAK_RATE * angle_rad / speed_rad_s,
               math.sqrt(PEAK_CURVATURE * distance_m / acceleration_m_s2),
               math.sqrt(PEAK_CURVATURE * angle_rad / acceleration_rad_s2))


def with_approach(reference: Reference, offset, duration_s: float, dt_s: float) -> Reference:
    """``reference`` preceded by a minimum-jerk move from ``reference.start - offset`` to
    its start (``offset``: the start minus where the machine is, angles wrapped, as
    laws.task_pose_error gives it) taking ``duration_s`` rounded up to whole cycles of
    ``dt_s``, sampled every cycle; the trajectory's times shifted by it. Each approach
    sample is anchored at the start (start - (1 - s) offset), so that its last one is
    the start exactly and an angle's 2 pi wrap is the trajectory's own."""
    n = max(1, math.ceil(duration_s / dt_s - 1e-9))
    total = n * dt_s
    start = reference.start
    times, xs, vs, accs = [], [], [], []
    for k in range(n):
        s, ds, dds = minimum_jerk(k / n)
        times.append(k * dt_s)
        xs.append([p - (1.0 - s) * e for p, e in zip(start, offset)])
        vs.append([e * ds / total for e in offset])
        accs.append([e * dds / (total * total) for e in offset])
    times.append(total)                                  # the start itself, once
    xs.append(list(start))
    vs.append(list(reference.velocity[0]))
    accs.append(list(reference.acceleration[0]))
    first = 1 if reference.time_s[0] == 0.0 else 0
    times.extend(total + t for t in reference.time_s[first:])
    out = Reference(times, xs + reference.position[first:], vs + reference.velocity[first:],
                    accs + reference.acceleration[first:])
    out.stamp_ns = reference.stamp_ns
    return out


def unwrap_angles(angles) -> list:
    """Continuous angles from angles given modulo 2 pi (yaw of a quaternion): each step
    is taken as the shortest one. The nacelle of a planar machine turns without limit,
    so a trajectory through +-pi must not jump by 2 pi."""
    out = []
    for a in angles:
        if out:
            a = unwrap_to(a, out[-1])
        out.append(float(a))
    return out


def reference_from_trajectory(data, space: TaskSpace) -> "Reference":
    """A MultiDOFJointTrajectory's arrays (``pkm_common.cdr.TrajectoryData``, joint
    "tool", as trajectory_node publishes) -> Reference in the task coordinates of
    ``space``: the yaw of a planar machine unwrapped (unlimited rotation); a spatial
    pose's roll, pitch and yaw, roll and yaw unwrapped, and their rates from the
    twists (``task_space.angle_rates_batch``, the inverse of what trajectory_node wrote)."""
    if len(data.joint_names) != 1 or not len(data.time_s):
        raise FieldError("trajectory", f"expected one joint 'tool' and at least one point, got "
                                       f"{list(data.joint_names)} with {len(data.time_s)} points")
    tf, vel, acc = data.transform[:, 0], data.velocity[:, 0], data.acceleration[:, 0]
    if space is PLANAR:  # (x, y, yaw about z); the yaw per point in Python floats, as the recorded runs had it
        yaw = unwrap_angles([yaw_of_quaternion(*q) for q in tf[:, 3:7].tolist()])
        return Reference(data.time_s, np.column_stack((tf[:, 0], tf[:, 1], yaw)), vel[:, [0, 1, 5]],
                         acc[:, [0, 1, 5]])
    if space is SPATIAL:
        angles = np.array([rpy_from_rotation(rotation_from_quaternion(q)) for q in tf[:, 3:7]]).reshape(-1, 3)
        angles[:, 0], angles[:, 2] = unwrap_angles(angles[:, 0]), unwrap_angles(angles[:, 2])
        rates, accelerations = angle_rates_batch(angles, vel[:, 3:6], acc[:, 3:6])
        return Reference(data.time_s, np.column_stack((tf[:, :3], angles)),
                         np.column_stack((vel[:, :3], rates)).reshape(-1, 6),
                         np.column_stack((acc[:, :3], accelerations)).reshape(-1, 6))
    return Reference(data.time_s, tf[:, :3], vel[:, :3], acc[:, :3])


def trajectory_data_from_msg(msg):
    """A MultiDOFJointTrajectory message object (rclpy, or deserialized from a
    recording by rosbags) as the arrays of ``pkm_common.cdr.decode_multidof_trajectory``."""
    n, j = len(msg.points), len(msg.joint_names)
    t, tf, vel, acc = np.zeros(n), np.zeros((n, j, 7)), np.zeros((n, j, 6)), np.zeros((n, j, 6))
    for k, p in enumerate(msg.points):
        t[k] = p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
        for i, f in enumerate(p.transforms[:j]):
            tf[k, i] = (f.translation.x, f.translation.y, f.translation.z,
                        f.rotation.x, f.rotation.y, f.rotation.z, f.rotation.w)
        for out, twists in ((vel, p.velocities), (acc, p.accelerations)):
            for i, w in enumerate(twists[:j]):
                out[k, i] = (w.linear.x, w.linear.y, w.linear.z, w.angular.x, w.angular.y, w.angular.z)
    stamp = msg.header.stamp
    return TrajectoryData(stamp.sec * 1_000_000_000 + stamp.nanosec, msg.header.frame_id, tuple(msg.joint_names),
                          t, tf, vel, acc)


def reference_from_msg(msg, space: TaskSpace) -> "Reference":
    """``reference_from_trajectory`` of a message object (duck-typed: rclpy or rosbags)."""
    return reference_from_trajectory(trajectory_data_from_msg(msg), space)
