"""The reference the controller tracks: a sampled task-space trajectory (pure core).

A trajectory is what ``pkm_trajectory`` plans and ``trajectory_node`` publishes:
times, positions, velocities and accelerations in task coordinates (planar
(x, y, theta), translational (x, y, z)). Between samples the reference is linearly
interpolated; before the start it is the first sample, after the end the last one at
rest (the machine holds the end pose). Sampling runs every control cycle, so it is
a bisection plus a few float operations (~2 us).
"""

from __future__ import annotations

import bisect
import math

import numpy as np


class Reference:
    """x_d(t), v_d(t), a_d(t) of a sampled trajectory, t relative to its start (s)."""

    def __init__(self, time_s, position, velocity=None, acceleration=None):
        t = np.asarray(time_s, dtype=float)
        x = np.asarray(position, dtype=float)
        if t.ndim != 1 or t.size < 1 or x.shape != (t.size, 3):
            raise ValueError(f"trajectory: expected N times and N x 3 positions, got shapes {t.shape}, {x.shape}")
        v = np.zeros_like(x) if velocity is None else np.asarray(velocity, dtype=float)
        a = np.zeros_like(x) if acceleration is None else np.asarray(acceleration, dtype=float)
        if v.shape != x.shape or a.shape != x.shape:
            raise ValueError(f"trajectory: velocities and accelerations must be N x 3 like the positions, "
                             f"got {v.shape}, {a.shape}")
        for name, arr in (("time_from_start", t), ("positions", x), ("velocities", v), ("accelerations", a)):
            if not np.isfinite(arr).all():
                raise ValueError(f"trajectory: {name} contain NaN or infinite values")
        if t.size > 1 and not (np.diff(t) > 0.0).all():
            k = int(np.argmax(np.diff(t) <= 0.0)) + 1
            raise ValueError(f"trajectory: time_from_start must increase strictly, point {k} is at "
                             f"{t[k]:.9g} s after {t[k - 1]:.9g} s")
        if t[0] < 0.0:
            raise ValueError(f"trajectory: time_from_start must be >= 0, got {t[0]:.9g} s")
        self.time_s = t.tolist()
        self.position = x.tolist()
        self.velocity = v.tolist()
        self.acceleration = a.tolist()

    @classmethod
    def hold(cls, pose) -> "Reference":
        """Stand still at ``pose``."""
        return cls([0.0], [list(pose)])

    @property
    def duration_s(self) -> float:
        return self.time_s[-1]

    @property
    def start(self) -> list:
        return self.position[0]

    @property
    def end(self) -> list:
        return self.position[-1]

    def sample(self, t: float) -> tuple[list, list, list]:
        """(x_d, v_d, a_d) at ``t`` seconds after the start."""
        ts = self.time_s
        if t <= ts[0]:
            return list(self.position[0]), list(self.velocity[0]), list(self.acceleration[0])
        if t >= ts[-1]:
            return list(self.position[-1]), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        k = bisect.bisect_right(ts, t)
        t0, t1 = ts[k - 1], ts[k]
        w = (t - t0) / (t1 - t0)
        u = 1.0 - w
        x0, x1 = self.position[k - 1], self.position[k]
        v0, v1 = self.velocity[k - 1], self.velocity[k]
        a0, a1 = self.acceleration[k - 1], self.acceleration[k]
        return ([u * p + w * q for p, q in zip(x0, x1)], [u * p + w * q for p, q in zip(v0, v1)],
                [u * p + w * q for p, q in zip(a0, a1)])


def unwrap_angles(angles) -> list:
    """Continuous angles from angles given modulo 2 pi (yaw of a quaternion): each step
    is taken as the shortest one. The nacelle of a planar machine turns without limit,
    so a trajectory through +-pi must not jump by 2 pi."""
    out = []
    for a in angles:
        if out:
            a += 2.0 * math.pi * round((out[-1] - a) / (2.0 * math.pi))
        out.append(float(a))
    return out


def reference_from_msg(msg, planar: bool) -> "Reference":
    """MultiDOFJointTrajectory (joint "tool", as trajectory_node publishes) -> Reference;
    the yaw of a planar machine unwrapped (unlimited rotation). Duck-typed: an rclpy
    message or one deserialized from a recording (rosbags) alike."""
    if len(msg.joint_names) != 1 or not msg.points:
        raise ValueError(f"trajectory: expected one joint 'tool' and at least one point, got "
                         f"{list(msg.joint_names)} with {len(msg.points)} points")
    t, x, v, a = [], [], [], []
    for p in msg.points:
        t.append(p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec)
        tf = p.transforms[0]
        vel = p.velocities[0] if p.velocities else None
        acc = p.accelerations[0] if p.accelerations else None
        if planar:
            r = tf.rotation
            x.append([tf.translation.x, tf.translation.y,
                      math.atan2(2.0 * (r.w * r.z + r.x * r.y), 1.0 - 2.0 * (r.y * r.y + r.z * r.z))])
            v.append([vel.linear.x, vel.linear.y, vel.angular.z] if vel else [0.0] * 3)
            a.append([acc.linear.x, acc.linear.y, acc.angular.z] if acc else [0.0] * 3)
        else:
            x.append([tf.translation.x, tf.translation.y, tf.translation.z])
            v.append([vel.linear.x, vel.linear.y, vel.linear.z] if vel else [0.0] * 3)
            a.append([acc.linear.x, acc.linear.y, acc.linear.z] if acc else [0.0] * 3)
    if planar:
        for row, theta in zip(x, unwrap_angles([row[2] for row in x])):
            row[2] = theta
    return Reference(t, x, v, a)
