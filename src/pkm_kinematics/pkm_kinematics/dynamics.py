"""Rigid-body dynamics in task coordinates (ARCHI §3.4), shared by the simulated plant
(true parameters) and the computed-torque controller (nominal parameters).

Drives of mass M_d slide on their rails with viscous friction k; the legs' own
dynamics are neglected (ARCHI: "arms dynamics is neglected"); the platform has mass
and, for planar machines, inertia M_n. Virtual work with qdot = J_m xdot and
qddot = J_m xddot + Jdot_m xdot gives

    (J^T M_d J + M_n) xddot + J^T M_d Jdot xdot + J^T k J xdot
        - J^T M_d g_u - M_n g = J^T f_d + f_n

i.e. A(x) xddot + H(x, xdot) = J^T f_d + f_n (the paper's f_n = A xddot + H form),
where g_u_i = g . u_i is gravity along rail i and f_n the external wrench on the
platform. The seed's closing equation mixes the signs of f_n, M_n g and J^T f_d; this
is the form that conserves energy (tested).

Everything runs on plain floats (3 DOF, 3-6 drives): ~15 us per evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .planar import PlanarMachine, _solve3


@dataclass(frozen=True)
class DynamicsParameters:
    """ARCHI §3.4 parameters (SI): M_d per drive, M_n (mass, and inertia for planar
    machines), viscous drive friction k per drive, gravity in the world frame
    (2 components for planar machines, 3 for translational ones)."""

    drive_mass_kg: tuple
    platform_mass_kg: float
    platform_inertia_kgm2: float
    friction_ns_per_m: tuple
    gravity_m_s2: tuple


class DynamicModel:
    """A(x), H(x, xdot), forward and inverse dynamics and energy of a machine."""

    def __init__(self, machine, params: DynamicsParameters):
        self.machine = machine
        self.params = params
        n = machine.n_legs
        if len(params.drive_mass_kg) != n or len(params.friction_ns_per_m) != n:
            raise ValueError(f"dynamics: drive_mass_kg and friction_ns_per_m need {n} entries")
        self.planar = isinstance(machine, PlanarMachine)
        m = params.platform_mass_kg
        g = tuple(float(v) for v in params.gravity_m_s2)
        rails = machine._u if self.planar else machine._e
        if len(g) != rails.shape[1]:
            raise ValueError(f"dynamics.gravity_m_s2: needs {rails.shape[1]} components, got {len(g)}")
        self._mn = (m, m, params.platform_inertia_kgm2 if self.planar else m)
        self._platform_gravity = (m * g[0], m * g[1], 0.0) if self.planar else (m * g[0], m * g[1], m * g[2])
        self._md = tuple(float(v) for v in params.drive_mass_kg)
        self._k = tuple(float(v) for v in params.friction_ns_per_m)
        # weight of each carriage along its rail: m_i g . u_i
        self._drive_gravity = tuple(mi * float(np.dot(g, u)) for mi, u in zip(self._md, rails))
        self._rail_origin_gravity = sum(mi * float(np.dot(g, o)) for mi, o in zip(self._md, machine._o))

    def terms(self, x, xdot):
        """(A as 3 rows, H (3,), J_m rows, q, qdot) at the state (x, xdot)."""
        q, rows, qdot, jdv = self.machine.velocity_terms(x, xdot)
        a00, a11, a22 = self._mn
        a01 = a02 = a12 = 0.0
        h0, h1, h2 = (-g for g in self._platform_gravity)
        for (j0, j1, j2), mi, ki, qd, b, gi in zip(rows, self._md, self._k, qdot, jdv, self._drive_gravity):
            a00 += mi * j0 * j0
            a01 += mi * j0 * j1
            a02 += mi * j0 * j2
            a11 += mi * j1 * j1
            a12 += mi * j1 * j2
            a22 += mi * j2 * j2
            c = mi * b + ki * qd - gi          # per-drive force not producing acceleration
            h0 += j0 * c
            h1 += j1 * c
            h2 += j2 * c
        a = ((a00, a01, a02), (a01, a11, a12), (a02, a12, a22))
        return a, (h0, h1, h2), rows, q, qdot

    def forward_dynamics(self, x, xdot, drive_forces, wrench=(0.0, 0.0, 0.0)) -> tuple:
        """xddot from A xddot = J^T f_d + f_n - H."""
        a, h, rows, _, _ = self.terms(x, xdot)
        r0, r1, r2 = wrench[0] - h[0], wrench[1] - h[1], wrench[2] - h[2]
        for (j0, j1, j2), f in zip(rows, drive_forces):
            r0 += j0 * f
            r1 += j1 * f
            r2 += j2 * f
        return _solve3(a, (r0, r1, r2))

    def inverse_dynamics(self, x, xdot, xddot, wrench=(0.0, 0.0, 0.0)) -> np.ndarray:
        """The platform wrench J^T f_d the drives must produce: A xddot + H - f_n."""
        a, h, _, _, _ = self.terms(x, xdot)
        return np.array([sum(a[i][j] * xddot[j] for j in range(3)) + h[i] - wrench[i] for i in range(3)])

    def energy(self, x, xdot) -> float:
        """Kinetic (1/2 xdot^T A xdot) plus potential energy (platform and carriages)."""
        a, _, _, q, _ = self.terms(x, xdot)
        kinetic = 0.5 * sum(xdot[i] * a[i][j] * xdot[j] for i in range(3) for j in range(3))
        gp = self._platform_gravity
        potential = -(gp[0] * x[0] + gp[1] * x[1] + (0.0 if self.planar else gp[2] * x[2]))
        potential -= sum(gi * qi for gi, qi in zip(self._drive_gravity, q)) + self._rail_origin_gravity
        return kinetic + potential

    def static_forces(self, x, wrench=(0.0, 0.0, 0.0)) -> np.ndarray:
        """The platform wrench the drives must produce to hold x still: H(x, 0) - f_n."""
        return self.inverse_dynamics(x, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), wrench)
