"""Rotation helpers (SO(3)): skew matrices, exponential map, RPY and quaternions.

Conventions: REP-103; roll-pitch-yaw is R = Rz(yaw) Ry(pitch) Rx(roll) (fixed axes
x, y, z); quaternions are (x, y, z, w) as in geometry_msgs.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import FieldError
from .jit import kernel


def unwrap_to(angle: float, reference: float) -> float:
    """``angle`` moved by whole turns to the one nearest ``reference``: a yaw on the
    revolution the machine is on (a planar nacelle turns without limit)."""
    return angle + 2.0 * math.pi * round((reference - angle) / (2.0 * math.pi))


unwrap_to_kernel = kernel()(unwrap_to)       # the same, for compiled kernels


def wrap_angle(angle: float) -> float:
    """``angle`` in (-pi, pi] (an angle inside it is returned as it is, bit for bit)."""
    return angle - 2.0 * math.pi * math.ceil((angle - math.pi) / (2.0 * math.pi))


def wrap_angles(angles: np.ndarray) -> np.ndarray:
    """wrap_angle of each element."""
    angles = np.asarray(angles, dtype=float)
    return angles - 2.0 * np.pi * np.ceil((angles - np.pi) / (2.0 * np.pi))


def yaw_of_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Rotation about z (rad, in (-pi, pi]) of the quaternion (x, y, z, w): a planar
    machine's yaw."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def yaw_of_quaternions(orientation: np.ndarray) -> np.ndarray:
    """yaw_of_quaternion of each row of an (N, 4) array (x, y, z, w)."""
    x, y, z, w = np.asarray(orientation, dtype=float).T
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def skew(v) -> np.ndarray:
    """Cross-product matrix: skew(a) @ b == a x b."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


@kernel()
def exp_so3_kernel(wx: float, wy: float, wz: float) -> tuple:
    """Rodrigues' formula on floats: the row-major 9-tuple of exp([w]x)."""
    theta2 = wx * wx + wy * wy + wz * wz
    if theta2 < 1e-16:
        # second-order expansion, exact to machine precision for tiny angles
        a, b = 1.0, 0.5
    else:
        theta = math.sqrt(theta2)
        a = math.sin(theta) / theta
        b = (1.0 - math.cos(theta)) / theta2
    return (1.0 - b * (wy * wy + wz * wz), -a * wz + b * wx * wy, a * wy + b * wx * wz,
            a * wz + b * wx * wy, 1.0 - b * (wx * wx + wz * wz), -a * wx + b * wy * wz,
            -a * wy + b * wx * wz, a * wx + b * wy * wz, 1.0 - b * (wx * wx + wy * wy))


# the same formula interpreted, for Python callers (a compiled call costs more than it
# saves on 9 floats); kernels call exp_so3_kernel
exp_so3_floats = exp_so3_kernel.py_func


def exp_so3(omega) -> np.ndarray:
    """Rodrigues' formula: the rotation by angle |omega| about omega/|omega|."""
    return np.array(exp_so3_floats(float(omega[0]), float(omega[1]), float(omega[2]))).reshape(3, 3)


@kernel()
def mul3_kernel(a, b) -> tuple:
    """Product of two rotations given as row-major 9-tuples of floats."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = a
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = b
    return (a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21,
            a00 * b02 + a01 * b12 + a02 * b22,
            a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21,
            a10 * b02 + a11 * b12 + a12 * b22,
            a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21,
            a20 * b02 + a21 * b12 + a22 * b22)


mul3 = mul3_kernel.py_func         # interpreted, for Python callers (see exp_so3_floats)


@kernel()
def mv3_kernel(r, v) -> tuple:
    """A rotation given as a row-major 9-tuple times a 3-vector (3 floats)."""
    x, y, z = v
    return (r[0] * x + r[1] * y + r[2] * z, r[3] * x + r[4] * y + r[5] * z,
            r[6] * x + r[7] * y + r[8] * z)


mv3 = mv3_kernel.py_func


@kernel()
def unit_quaternion_rotation_kernel(x: float, y: float, z: float, w: float) -> tuple:
    """The rotation (row-major 9-tuple) of a unit quaternion (x, y, z, w)."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w),
            2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w),
            2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y))


unit_quaternion_rotation_floats = unit_quaternion_rotation_kernel.py_func


@kernel()
def shepperd_kernel(r) -> tuple:
    """The quaternion (x, y, z, w) of a rotation given as a row-major 9-tuple by
    Shepperd's method, before its normalisation and sign (from the largest of the
    trace and the diagonal: no division by a small number)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        return (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s, 0.25 * s
    if r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        return 0.25 * s, (r01 + r10) / s, (r02 + r20) / s, (r21 - r12) / s
    if r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        return (r01 + r10) / s, 0.25 * s, (r12 + r21) / s, (r02 - r20) / s
    s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
    return (r02 + r20) / s, (r12 + r21) / s, 0.25 * s, (r10 - r01) / s


@kernel()
def rotation_quaternion_kernel(r) -> tuple:
    """Unit quaternion (x, y, z, w), w >= 0, of a rotation given as a row-major 9-tuple
    (:func:`shepperd_kernel`, normalised by its scalar norm)."""
    q0, q1, q2, q3 = shepperd_kernel(r)
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if q3 < 0.0:
        n = -n
    return (q0 / n, q1 / n, q2 / n, q3 / n)


rotation_quaternion_floats = rotation_quaternion_kernel.py_func


@kernel()
def log_so3_kernel(r) -> tuple:
    """The rotation vector (3 floats) of a rotation given as a row-major 9-tuple
    (angle < pi): the inverse of :func:`exp_so3_kernel`."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    cos_t = max(-1.0, min(1.0, 0.5 * (r00 + r11 + r22 - 1.0)))
    theta = math.acos(cos_t)
    v0, v1, v2 = r21 - r12, r02 - r20, r10 - r01
    if theta < 1e-8:
        return 0.5 * v0, 0.5 * v1, 0.5 * v2
    if math.pi - theta < 1e-6:
        # near pi: the axis from the symmetric part, its signs from v
        a0 = math.sqrt(max(r00 - cos_t, 0.0) / (1.0 - cos_t))
        a1 = math.sqrt(max(r11 - cos_t, 0.0) / (1.0 - cos_t))
        a2 = math.sqrt(max(r22 - cos_t, 0.0) / (1.0 - cos_t))
        if v0 != 0.0 or v1 != 0.0 or v2 != 0.0:
            a0, a1, a2 = math.copysign(a0, v0), math.copysign(a1, v1), math.copysign(a2, v2)
        k = theta / math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        return k * a0, k * a1, k * a2
    k = theta / (2.0 * math.sin(theta))
    return k * v0, k * v1, k * v2


log_so3_floats = log_so3_kernel.py_func     # interpreted, for Python callers


def log_so3(rotation: np.ndarray) -> np.ndarray:
    """Inverse of :func:`exp_so3`: the rotation vector of ``rotation`` (angle < pi)."""
    return np.array(log_so3_floats(tuple(np.asarray(rotation, dtype=float).ravel().tolist())))


@kernel()
def rpy_rotation_kernel(roll: float, pitch: float, yaw: float) -> tuple:
    """R = Rz(yaw) Ry(pitch) Rx(roll) as a row-major 9-tuple."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
            sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
            -sp, cp * sr, cp * cr)


rpy_rotation_floats = rpy_rotation_kernel.py_func


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return np.array(rpy_rotation_floats(roll, pitch, yaw)).reshape(3, 3)


@kernel()
def rpy_kernel(r00: float, r10: float, r20: float, r21: float, r22: float) -> tuple:
    """Roll, pitch, yaw of a rotation from its entries r00, r10, r20, r21, r22
    (the inverse of :func:`rpy_rotation_kernel`, |pitch| < pi/2)."""
    return math.atan2(r21, r22), math.atan2(-r20, math.hypot(r00, r10)), math.atan2(r10, r00)


def rpy_from_rotation(rotation: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw of ``rotation`` (inverse of :func:`rotation_from_rpy`)."""
    r = rotation
    return rpy_kernel.py_func(r[0, 0], r[1, 0], r[2, 0], r[2, 1], r[2, 2])


@kernel()
def rate_matrix_kernel(b: float, c: float) -> tuple:
    """:func:`rate_matrix` as a row-major 9-tuple (it does not depend on a)."""
    cb, sb = math.cos(b), math.sin(b)
    cc, sc = math.cos(c), math.sin(c)
    return (cc * cb, -sc, 0.0, sc * cb, cc, 0.0, -sb, 0.0, 1.0)


@kernel()
def rate_matrix_derivative_kernel(b: float, c: float, b_rate: float, c_rate: float) -> tuple:
    """:func:`rate_matrix_derivative` as a row-major 9-tuple."""
    cb, sb = math.cos(b), math.sin(b)
    cc, sc = math.cos(c), math.sin(c)
    return (-sc * c_rate * cb - cc * sb * b_rate, -cc * c_rate, 0.0,
            cc * c_rate * cb - sc * sb * b_rate, -sc * c_rate, 0.0,
            -cb * b_rate, 0.0, 0.0)


def rate_matrix(a: float, b: float, c: float) -> np.ndarray:
    """E with w = E (a', b', c') for R = Rz(c) Ry(b) Rx(a): the angular velocity in
    the base frame of the rotation angles' rates (c about z, b about the once-turned
    y, a about the twice-turned x; a, the last rotation applied, does not move the axes)."""
    return np.array(rate_matrix_kernel.py_func(b, c)).reshape(3, 3)


def rate_matrix_derivative(b: float, c: float, b_rate: float, c_rate: float) -> np.ndarray:
    """dE/dt of :func:`rate_matrix` (it depends on b and c only): the angular
    acceleration is w' = E (a'', b'', c'') + E' (a', b', c')."""
    return np.array(rate_matrix_derivative_kernel.py_func(b, c, b_rate, c_rate)).reshape(3, 3)


@kernel()
def angular_motion_kernel(b, c, ra, rb, rc, aa, ab, ac) -> tuple:
    """(w, w') of roll-pitch-yaw angles (a, b, c) moving at rates (ra, rb, rc) with
    accelerations (aa, ab, ac): w = E r, w' = E acc + E' r (6 floats)."""
    e = rate_matrix_kernel(b, c)
    d = rate_matrix_derivative_kernel(b, c, rb, rc)
    return (e[0] * ra + e[1] * rb + e[2] * rc, e[3] * ra + e[4] * rb + e[5] * rc, e[6] * ra + e[7] * rb + e[8] * rc,
            e[0] * aa + e[1] * ab + e[2] * ac + (d[0] * ra + d[1] * rb + d[2] * rc),
            e[3] * aa + e[4] * ab + e[5] * ac + (d[3] * ra + d[4] * rb + d[5] * rc),
            e[6] * aa + e[7] * ab + e[8] * ac + (d[6] * ra + d[7] * rb + d[8] * rc))


angular_motion_floats = angular_motion_kernel.py_func


@kernel("(float64[:, :], float64)")
def first_improper_rotation_kernel(rotations, tol):
    """The index of the first row of ``rotations`` (N, 9, row-major) that is not a
    rotation matrix (an entry of R^T R - I above ``tol``, or det(R) <= 0), or -1.
    Compiled: numpy's batched R^T R and det cost more than a warm-started FK."""
    for n in range(rotations.shape[0]):
        r = rotations[n]
        for i in range(3):
            for j in range(3):
                s = r[i] * r[j] + r[3 + i] * r[3 + j] + r[6 + i] * r[6 + j]
                if not abs(s - (1.0 if i == j else 0.0)) <= tol:    # (NaN is improper)
                    return n
        det = (r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6])
               + r[2] * (r[3] * r[7] - r[4] * r[6]))
        if not det > 0.0:
            return n
    return -1


def rotation_about_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quaternion_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), w >= 0, of a rotation matrix (Shepperd's method)."""
    return quaternion_from_rotation_floats(np.asarray(rotation, dtype=float).ravel().tolist())


def quaternion_from_rotation_floats(r) -> np.ndarray:
    """:func:`quaternion_from_rotation` of a rotation as 9 floats, row-major (a spatial
    machine's reference pose every step). Normalised by numpy's norm, not
    :func:`rotation_quaternion_kernel`'s: that one differs in the last bit, which moves
    a hexapod's trajectory and then its commands (golden compare: 30 differences on
    the five hexapod scenarios); one of them is to go with a deliberate re-recording."""
    q = np.array(shepperd_kernel.py_func(r))
    if q[3] < 0.0:
        q = -q
    return q / np.linalg.norm(q)


def rotation_from_quaternion(q) -> np.ndarray:
    """Rotation matrix of quaternion (x, y, z, w); the quaternion is normalized first."""
    x, y, z, w = (float(c) for c in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 0.0 or not math.isfinite(n):
        raise FieldError("quaternion", f"must be finite and non-zero, got {q!r}")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
