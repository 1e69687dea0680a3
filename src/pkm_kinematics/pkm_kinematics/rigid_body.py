"""Rigid-body dynamics of a 6-DOF platform on actuated struts (Newton-Euler in SE(3)),
for the hexapods' simulated plant and computed-torque control (issue 23).

The platform: mass m, inertia I_p about its point p in its own frame (I_w = R I_p R^T
in the base frame). Each strut's drive: a mass M_d along its length (the reflected
inertia of its motor and screw: no weight of its own along the strut, which turns),
viscous friction k. With the twist t = (v, w) (w in the base frame), q' = J_m t and
q'' = J_m t' + J_m' t, virtual work gives (ARCHI §3.4's form, extended to SE(3) by
the Euler term):

    A t' + H = J_m^T f_d + f_n
    A = J_m^T M_d J_m + blockdiag(m 1, I_w)
    H = J_m^T (M_d J_m' t + k J_m t) + (0, w x I_w w) - (m g, 0)

f_n the external wrench on the platform (force, moment about p, base frame). With
no drive force, friction or load, the energy 1/2 t^T blockdiag(m, I_w) t +
1/2 q'^T M_d q' - m g . p is constant (tested, and the derivation: w . (w x I_w w) = 0
and d/dt I_w = [w]x I_w - I_w [w]x). Restricted to planar motion (w along z, z a
principal axis of I_p: no Euler term) it is the form of the planar machines'
DynamicModel (dynamics.py), whose drives on rails also carry their weight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import bars as B
from .distribution import least_squares_n_kernel
from .errors import FieldError, SingularityError
from .struts import CYCLE_FK, StrutMachine, task_forward_kinematics_kernel
from .jit import kernel
from .rotations import exp_so3_kernel, mul3_kernel, rpy_rotation_kernel


@dataclass(frozen=True)
class RigidBodyParameters:
    """SI: platform mass and inertia (3 x 3, platform frame, about the platform point),
    per-drive mass and viscous friction, gravity (3, base frame)."""
    platform_mass_kg: float
    platform_inertia_kgm2: tuple
    drive_mass_kg: tuple
    friction_ns_per_m: tuple
    gravity_m_s2: tuple = (0.0, 0.0, -9.81)


class StrutDynamics:
    """A(x), H(x, t), forward and inverse dynamics and energy of a strut machine;
    x the task coordinates (x, y, z, a, b, c), t the twist (v, w)."""

    def __init__(self, machine: StrutMachine, params: RigidBodyParameters):
        n = machine.n_legs
        if len(params.drive_mass_kg) != n or len(params.friction_ns_per_m) != n:
            raise FieldError("dynamics", f"drive_mass_kg and friction_ns_per_m need {n} entries")
        inertia = np.asarray(params.platform_inertia_kgm2, dtype=float).reshape(3, 3)
        if not np.allclose(inertia, inertia.T) or np.linalg.eigvalsh(inertia).min() <= 0.0:
            raise ValueError(f"dynamics.platform_inertia_kgm2: must be symmetric positive definite, got {inertia}")
        if not params.platform_mass_kg > 0.0:
            raise ValueError(f"dynamics.platform_mass_kg: must be > 0, got {params.platform_mass_kg}")
        self.machine, self.params = machine, params
        self._inertia = inertia
        self._md = np.asarray(params.drive_mass_kg, dtype=float)
        self._k = np.asarray(params.friction_ns_per_m, dtype=float)
        self._g = np.asarray(params.gravity_m_s2, dtype=float).reshape(3)

    def inertia_world(self, x) -> np.ndarray:
        """I_w = R I_p R^T."""
        _, rot = self.machine.pose(x)
        return rot @ self._inertia @ rot.T

    def terms(self, x, twist) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A (6, 6), H (6,), J_m (n, 6)) at the state (x, t) (module doc)."""
        p, rot = self.machine.pose(x)
        return self.terms_at(p, rot, twist)

    def terms_at(self, position, rotation, twist) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`terms` at the pose (p, R) (``strut_dynamics_terms_kernel``)."""
        ok, a, h, jac = strut_dynamics_terms_kernel(
            self.machine.bars, np.ascontiguousarray(position, dtype=float), np.ascontiguousarray(rotation).ravel(),
            np.ascontiguousarray(twist, dtype=float).ravel(), self._md, self._k, self._inertia.ravel(),
            float(self.params.platform_mass_kg), self._g)
        if not ok:
            raise SingularityError(f"a strut has zero length at p = {np.asarray(position).tolist()}")
        return a, h, jac

    def measured_state(self, x, drive_velocities) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, H, J_m, t) at the pose x with the twist t = J_m^+ q' that best explains
        the drive velocities (least squares: the exact twist when they agree), what a
        controller derives from its encoders every cycle (``DynamicModel.measured_state``
        of the rail machines). SingularityError when J_m has rank < 6."""
        qdot = np.asarray(drive_velocities, dtype=float)
        if qdot.shape != (self.machine.n_legs,):
            raise FieldError("drive_velocities", f"expected {self.machine.n_legs} values, got shape {qdot.shape}")
        code, a, h, jac, twist = strut_measured_state_kernel(
            self.machine.bars, np.asarray(x, dtype=float), qdot, self._md, self._k, self._inertia.ravel(),
            float(self.params.platform_mass_kg), self._g)
        if code:
            raise SingularityError(f"{'a strut has zero length' if code == 1 else 'J_m has rank < 6'} at x = "
                                   f"{np.asarray(x).tolist()}")
        return a, h, jac, twist

    def encoder_state(self, q: np.ndarray, guess, drive_velocities) -> tuple:
        """The forward kinematics of the strut readings ``q`` (n floats, an array) from
        ``guess`` (the home when None) and :meth:`measured_state` there, in one compiled
        call (:func:`strut_encoder_state_kernel`): (pose (6 floats) or None, (A, H, J_m,
        t) or None), the pose the machine's ``forward_kinematics_floats`` gives. None for
        what the call refused: ``forward_kinematics_floats``, or ``measured_state``,
        raises it (controller.pose_estimation's fused encoder state, as the rail
        machines' ``DynamicModel.encoder_state``)."""
        qdot = np.array(drive_velocities, dtype=float)
        n = self.machine.n_legs
        if q.shape != (n,) or q.dtype != np.float64 or qdot.shape != (n,):
            return None, None
        g = self.machine.home if guess is None else guess
        fk, x, code, a, h, jac, twist = strut_encoder_state_kernel(
            self.machine.bars, q, (float(g[0]), float(g[1]), float(g[2]), float(g[3]), float(g[4]), float(g[5])),
            qdot, *self.step_arguments())
        if fk != B.FK_CONVERGED:
            return None, None
        return x, ((a, h, jac, twist) if code == 0 else None)

    def step_arguments(self) -> tuple:
        """What :func:`strut_step_kernel` takes of this model after the state, forces and
        wrench, for a compiled caller's step (pkm_sim_hw.strut_step): (M_d, friction,
        I_p row-major, platform mass, gravity)."""
        return self._md, self._k, self._inertia.ravel(), float(self.params.platform_mass_kg), self._g

    def step(self, position, rotation, twist, drive_forces, wrench, h: float, substeps: int = 1):
        """(p, R, t) after ``substeps`` semi-implicit Euler steps of h (``strut_step_kernel``);
        SingularityError when a strut reaches zero length."""
        ok, p, r, t = strut_step_kernel(self.machine.bars, np.asarray(position, dtype=float),
                                        np.ascontiguousarray(rotation, dtype=float).ravel(),
                                        np.asarray(twist, dtype=float), np.asarray(drive_forces, dtype=float),
                                        np.asarray(wrench, dtype=float), *self.step_arguments(), float(h),
                                        int(substeps))
        if not ok:
            raise SingularityError(f"a strut has zero length at p = {p.tolist()}")
        return p, r.reshape(3, 3), t

    def forward_dynamics(self, x, twist, drive_forces, wrench=np.zeros(6)) -> np.ndarray:
        """t' from A t' = J_m^T f_d + f_n - H."""
        p, rot = self.machine.pose(x)
        return self.forward_dynamics_at(p, rot, twist, drive_forces, wrench)

    def forward_dynamics_at(self, position, rotation, twist, drive_forces, wrench=np.zeros(6)) -> np.ndarray:
        """:meth:`forward_dynamics` at the pose (p, R)."""
        a, h, jac = self.terms_at(position, rotation, twist)
        return np.linalg.solve(a, jac.T @ np.asarray(drive_forces, dtype=float) + np.asarray(wrench, float) - h)

    def inverse_dynamics(self, x, twist, twist_dot, wrench=np.zeros(6)) -> np.ndarray:
        """The platform wrench J_m^T f_d the drives must produce: A t' + H - f_n."""
        a, h, _ = self.terms(x, twist)
        return a @ np.asarray(twist_dot, dtype=float) + h - np.asarray(wrench, dtype=float)

    def static_forces(self, x, wrench=np.zeros(6)) -> np.ndarray:
        """The platform wrench that holds x still: H(x, 0) - f_n."""
        return self.inverse_dynamics(x, np.zeros(6), np.zeros(6), wrench)

    def energy(self, x, twist) -> float:
        """Kinetic (platform and drives) plus the platform's potential energy."""
        t = np.asarray(twist, dtype=float).reshape(6)
        p, _ = self.machine.pose(x)
        qdot = self.machine.jacobian(x) @ t
        kinetic = 0.5 * self.params.platform_mass_kg * float(t[:3] @ t[:3]) \
            + 0.5 * float(t[3:] @ self.inertia_world(x) @ t[3:]) + 0.5 * float(qdot @ (self._md * qdot))
        return kinetic - self.params.platform_mass_kg * float(self._g @ p)


__all__ = ["RigidBodyParameters", "StrutDynamics"]


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:], float64[:], float64[:], float64, float64[:])")
def strut_dynamics_terms_kernel(bars, p, r, t, md, kf, inertia_p, mass, g):
    """(ok, A, H, J_m) of the module doc's equations at the pose (p, R: r row-major) and
    twist t: each strut's row of J_m and its rate along t (``bars.unit_row``,
    ``bars.unit_row_rate``, MoM3 eq. 2 and its derivative); A = J^T M_d J +
    blockdiag(m 1, R I_p R^T), H = J^T (M_d J' t + k J t) + (0, w x I_w w) - (m g, 0).
    ``bars``: the strut machine's (one bar a strut); ok False when a strut has zero length."""
    n = bars.shape[0]
    a = np.zeros((6, 6))
    h = np.zeros(6)
    jac = np.empty((n, 6))
    rt = (r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8])
    held = np.zeros(n)
    for k in range(n):
        length, u0, u1, u2, m0, m1, m2 = B.unit_row(bars, k, p[0], p[1], p[2], rt, held)
        if not length > 0.0:
            return False, a, h, jac
        d0, d1, d2, d3, d4, d5 = B.unit_row_rate(bars, k, p[0], p[1], p[2], rt, held, t[0], t[1], t[2], t[3],
                                                 t[4], t[5])
        jac[k, 0], jac[k, 1], jac[k, 2], jac[k, 3], jac[k, 4], jac[k, 5] = u0, u1, u2, m0, m1, m2
        qdot = u0 * t[0] + u1 * t[1] + u2 * t[2] + m0 * t[3] + m1 * t[4] + m2 * t[5]
        jdot_t = d0 * t[0] + d1 * t[1] + d2 * t[2] + d3 * t[3] + d4 * t[4] + d5 * t[5]
        coefficient = md[k] * jdot_t + kf[k] * qdot
        for i in range(6):
            h[i] += jac[k, i] * coefficient
            for j in range(6):
                a[i, j] += md[k] * jac[k, i] * jac[k, j]
    w0, w1, w2 = t[3], t[4], t[5]
    inertia_w = np.zeros((3, 3))                       # R I_p R^T
    for i in range(3):
        for j in range(3):
            s = 0.0
            for m in range(3):
                for l in range(3):
                    s += r[3 * i + m] * inertia_p[3 * m + l] * r[3 * j + l]
            inertia_w[i, j] = s
    for i in range(3):
        a[i, i] += mass
        for j in range(3):
            a[3 + i, 3 + j] += inertia_w[i, j]
    iw0 = inertia_w[0, 0] * w0 + inertia_w[0, 1] * w1 + inertia_w[0, 2] * w2
    iw1 = inertia_w[1, 0] * w0 + inertia_w[1, 1] * w1 + inertia_w[1, 2] * w2
    iw2 = inertia_w[2, 0] * w0 + inertia_w[2, 1] * w1 + inertia_w[2, 2] * w2
    h[3] += w1 * iw2 - w2 * iw1
    h[4] += w2 * iw0 - w0 * iw2
    h[5] += w0 * iw1 - w1 * iw0
    for i in range(3):
        h[i] -= mass * g[i]
    return True, a, h, jac


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:], float64[:], float64[:], float64[:], "
        "float64[:], float64, float64[:], float64, int64)")
def strut_step_kernel(bars, p, r, t, forces, load, md, kf, inertia_p, mass, g, h, substeps):
    """(ok, p, r, t) after ``substeps`` steps of h of the semi-implicit Euler rule on
    SE(3) (the hexapods' plant, ``pkm_sim_hw.strut_plant``): t += h A^-1 (J_m^T f + f_n
    - H); p += h v; R = exp(h [w]x) R, so R stays a rotation. ok False (and the state
    of the last good substep) when a strut has zero length."""
    p, r, t = p.copy(), r.copy(), t.copy()
    for _ in range(substeps):
        ok, a, hv, jac = strut_dynamics_terms_kernel(bars, p, r, t, md, kf, inertia_p, mass, g)
        if not ok:
            return False, p, r, t
        rhs = load - hv
        for i in range(6):
            for k in range(jac.shape[0]):
                rhs[i] += jac[k, i] * forces[k]
        t = t + h * np.linalg.solve(a, rhs)
        for i in range(3):
            p[i] += h * t[i]
        e = exp_so3_kernel(h * t[3], h * t[4], h * t[5])
        rt = mul3_kernel(e, (r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]))
        for i in range(9):
            r[i] = rt[i]
    return True, p, r, t


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:], float64[:], float64, float64[:])")
def strut_measured_state_kernel(bars, x, qdot, md, kf, inertia_p, mass, g):
    """(code, A, H, J_m, t) of ``StrutDynamics.measured_state`` at the task coordinates
    x: J_m, the least-squares twist t of the drive velocities, A and H at (x, t). code
    1: a strut of zero length; 2: J_m of rank < 6."""
    r = np.array(rpy_rotation_kernel(x[3], x[4], x[5]))
    p = x[:3].copy()
    ok, a, h, jac = strut_dynamics_terms_kernel(bars, p, r, np.zeros(6), md, kf, inertia_p, mass, g)
    twist = np.zeros(6)
    if not ok:
        return 1, a, h, jac, twist
    twist, solvable = least_squares_n_kernel(jac, qdot)
    if not solvable:
        return 2, a, h, jac, twist
    ok, a, h, jac = strut_dynamics_terms_kernel(bars, p, r, twist, md, kf, inertia_p, mass, g)
    return 0, a, h, jac, twist


@kernel("(float64[:, :], float64[:], UniTuple(float64, 6), float64[:], float64[:], float64[:], float64[:], float64, "
        "float64[:])")
def strut_encoder_state_kernel(bars, q, guess, qdot, md, kf, inertia_p, mass, g):
    """A strut machine's encoder state in one call (StrutDynamics.encoder_state): the
    forward kinematics of the readings ``q`` from ``guess``
    (``struts.task_forward_kinematics_kernel`` with the cycle's ``CYCLE_FK``), then
    :func:`strut_measured_state_kernel` there. Returns (the solve's code, x, the state's
    code, A, H, J_m, t); -1 for readings that are not finite positive lengths (none
    solved, as ``forward_kinematics_floats`` refuses them)."""
    n = bars.shape[0]
    a, h, jac, twist = np.zeros((6, 6)), np.zeros(6), np.zeros((n, 6)), np.zeros(6)
    for i in range(n):
        if not (math.isfinite(q[i]) and q[i] > 0.0):
            return -1, guess, 1, a, h, jac, twist
    code, _, _, x = task_forward_kinematics_kernel(bars, q, guess, CYCLE_FK[0], CYCLE_FK[1], CYCLE_FK[2])
    if code != B.FK_CONVERGED:
        return code, x, 1, a, h, jac, twist
    state, a, h, jac, twist = strut_measured_state_kernel(bars, np.array([x[0], x[1], x[2], x[3], x[4], x[5]]), qdot,
                                                          md, kf, inertia_p, mass, g)
    return code, x, state, a, h, jac, twist
