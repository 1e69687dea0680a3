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

from dataclasses import dataclass

import numpy as np

from .hexapod import StrutMachine
from .rotations import cross_rows


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
            raise ValueError(f"dynamics: drive_mass_kg and friction_ns_per_m need {n} entries")
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
        t = np.asarray(twist, dtype=float).reshape(6)
        jac = self.machine.jacobian(x)
        jdot_t = self.machine.jacobian_derivative(x, t) @ t
        inertia = self.inertia_world(x)
        a = jac.T @ (self._md[:, None] * jac)
        a[:3, :3] += self.params.platform_mass_kg * np.eye(3)
        a[3:, 3:] += inertia
        w = t[3:]
        h = jac.T @ (self._md * jdot_t + self._k * (jac @ t))
        h[3:] += cross_rows(w, inertia @ w)
        h[:3] -= self.params.platform_mass_kg * self._g
        return a, h, jac

    def forward_dynamics(self, x, twist, drive_forces, wrench=np.zeros(6)) -> np.ndarray:
        """t' from A t' = J_m^T f_d + f_n - H."""
        a, h, jac = self.terms(x, twist)
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
