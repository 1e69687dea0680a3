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

Per evaluation: the machine's compiled velocity terms, then A and H in one compiled
loop over the drives (:func:`_mass_terms_kernel`). ``measured_state`` is what a
controller needs from its encoders each cycle (J_m, the task velocity that best
explains the drive velocities, A and H there) in one compiled call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import bars as B
from .distribution import SINGULAR_GRAM, least_squares_kernel, min_two_norm
from .errors import DistributionError, FieldError
from .jit import direct_call, kernel
from .planar import (FK_CONVERGED, FK_MAX_ITERATIONS, FK_TOL, PlanarLeastSquaresFK, forward_kinematics_kernel,
                     solve3_kernel)
from .translational import ThreeSpheresFK
from .rigid_body import RigidBodyParameters, StrutDynamics
from .task_space import PLANAR

VT_LEAST_SQUARES_SINGULAR = 3          # measured_state: J_m^T J_m not invertible (after bars.VT_*)
STEP_SINGULAR_MASS = 4                 # semi_implicit_step: A(x) not invertible


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
            raise FieldError("dynamics", f"drive_mass_kg and friction_ns_per_m need {n} entries")
        self.planar = machine.task_space is PLANAR       # the platform turns: M_n has an inertia
        m = params.platform_mass_kg
        g = tuple(float(v) for v in params.gravity_m_s2)
        rails = machine.rail_directions
        if len(g) != rails.shape[1]:
            raise ValueError(f"dynamics.gravity_m_s2: needs {rails.shape[1]} components, got {len(g)}")
        self._mn = (m, m, params.platform_inertia_kgm2 if self.planar else m)
        self._platform_gravity = (m * g[0], m * g[1], 0.0) if self.planar else (m * g[0], m * g[1], m * g[2])
        self._md = tuple(float(v) for v in params.drive_mass_kg)
        self._k = tuple(float(v) for v in params.friction_ns_per_m)
        # weight of each carriage along its rail: m_i g . u_i
        self._drive_gravity = tuple(mi * float(np.dot(g, u)) for mi, u in zip(self._md, rails))
        self._rail_origin_gravity = sum(mi * float(np.dot(g, o)) for mi, o in zip(self._md, machine.rail_origins))
        self._mass_args = (np.array(self._md), np.array(self._k), np.array(self._drive_gravity),
                           *(float(v) for v in self._mn + self._platform_gravity))
        fk = getattr(machine, "fk", None)          # the rail machines' forward solver, on the machine's own bars
        self._fk_kind = None if getattr(fk, "bars", None) is not getattr(machine, "bars", None) else \
            "planar" if isinstance(fk, PlanarLeastSquaresFK) else "spheres" if isinstance(fk, ThreeSpheresFK) else None
        self.encoder_state = self._encoder_state if self._fk_kind else None

    def terms(self, x, xdot):
        """(A as 3 rows, H (3,), J_m rows, q, qdot) at the state (x, xdot)."""
        q, rows, qdot, jdv = self.machine.velocity_terms_arrays(x, xdot)
        a00, a01, a02, a11, a12, a22, h0, h1, h2 = _mass_terms_kernel(rows, qdot, jdv, *self._mass_args)
        return ((a00, a01, a02), (a01, a11, a12), (a02, a12, a22)), (h0, h1, h2), rows.tolist(), q.tolist(), \
            qdot.tolist()

    def measured_state(self, x, drive_velocities) -> tuple:
        """(A as 3 rows, H (3,), J_m as an (n, 3) array, v as a tuple of 3 floats) at the pose x
        with the task velocity v = (J_m^T J_m)^-1 J_m^T qdot that best explains the
        drive velocities (the exact one when they are consistent): what a controller
        derives from its encoders every cycle, in one compiled call. Raises like
        ``terms`` (unreachable, serial singularity) and DistributionError when J_m
        has rank < 3."""
        qdot = np.array(drive_velocities, dtype=float)
        if qdot.shape != (self.machine.n_legs,):
            raise FieldError("drive_velocities", f"expected {self.machine.n_legs} values, got shape {qdot.shape}")
        rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, code, leg = _measured_state_kernel(
            self.machine.bars, self.machine.twist_columns, x[0], x[1], x[2], qdot, *self._mass_args)
        if code == VT_LEAST_SQUARES_SINGULAR:
            raise DistributionError(SINGULAR_GRAM)
        if code != B.VT_OK:
            self.machine.raise_velocity_terms_error(code, leg, x)
        return _measured_state(rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2)

    def _encoder_state(self, q: np.ndarray, guess, drive_velocities) -> tuple:
        """The forward kinematics of the drive positions ``q`` (n floats, an array;
        planar: Newton from ``guess``, else from home) and :meth:`measured_state` there
        in one compiled call: (pose (3 floats) or None, (A, H, J_m, v) or None). None
        for what the call refused (the forward kinematics, or the measured state):
        the machine's ``forward_kinematics_floats``, or ``measured_state``, raises it.
        ``encoder_state`` is this for a machine whose forward solver has such a kernel
        (planar least squares, three spheres), else None."""
        qdot = np.array(drive_velocities, dtype=float)
        n = self.machine.n_legs
        if q.shape != (n,) or qdot.shape != (n,):
            return None, None
        fk = self.machine.fk
        if self._fk_kind == "planar":
            ref = self.machine.home if guess is None else guess
            out = _planar_encoder_state(fk.bars, fk.pairs_array, fk.sides, q, float(ref[0]), float(ref[1]),
                                        float(ref[2]), self.machine.twist_columns, qdot, *self._mass_args)
        else:
            out = _spheres_encoder_state(fk.bars, fk.side, q, self.machine.twist_columns, qdot, *self._mass_args)
        x0, x1, x2, solved, rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, code, _ = out
        if not solved:
            return None, None
        if code != B.VT_OK:
            return (x0, x1, x2), None
        return (x0, x1, x2), _measured_state(rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2)

    def encoder_state_inputs(self) -> tuple | None:
        """What :func:`rail_encoder_state_kernel` takes of this machine: (spheres, the
        forward solver's bars, pairs, sides, side), then after q and the guess (columns,
        then the mass model's 9); None when ``encoder_state`` is."""
        if self._fk_kind is None:
            return None
        fk = self.machine.fk
        if self._fk_kind == "planar":
            head = (False, fk.bars, fk.pairs_array, fk.sides, 0.0)
        else:
            head = (True, fk.bars, np.zeros((0, 2), dtype=np.int64), np.zeros(0), float(fk.side))
        return head, (self.machine.twist_columns, *self._mass_args)

    def forward_dynamics(self, x, xdot, drive_forces, wrench=(0.0, 0.0, 0.0)) -> tuple:
        """xddot from A xddot = J^T f_d + f_n - H (:func:`forward_acceleration_kernel`)."""
        _, rows, qdot, jdv = self.machine.velocity_terms_arrays(x, xdot)
        forces = np.asarray(drive_forces, dtype=float)
        if forces.shape != (rows.shape[0],):
            raise FieldError("drive_forces", f"expected {rows.shape[0]} values, got shape {forces.shape}")
        a0, a1, a2, ok = forward_acceleration_kernel(rows, qdot, jdv, forces, wrench[0], wrench[1], wrench[2],
                                                     *self._mass_args)
        if not ok:
            raise np.linalg.LinAlgError("singular 3x3 system")
        return a0, a1, a2

    def step_arguments(self) -> tuple:
        """What :func:`semi_implicit_step_kernel` takes of this model, for a compiled
        caller's step (pkm_sim_hw.rail_step): (bars, twist columns, then the mass
        model's md, k, drive gravity, mn0, mn1, mn2, pg0, pg1, pg2)."""
        return (self.machine.bars, self.machine.twist_columns, *self._mass_args)

    def semi_implicit_step(self, x, xdot, drive_forces, wrench, h: float, substeps: int) -> tuple:
        """``substeps`` semi-implicit Euler steps of ``forward_dynamics`` (xdot += h xddot,
        then x += h xdot) under constant forces and wrench, and the velocity terms at the
        state reached, in one compiled call (:func:`semi_implicit_step_kernel`): the
        simulated plant's step, the same floats as the step written in Python. Returns
        (x, xdot, (q, J_m rows, q', J_m' x') as lists); raises like ``terms`` (naming the
        pose where it failed) and LinAlgError where A(x) is singular."""
        forces = np.asarray(drive_forces, dtype=float)
        if forces.shape != (self.machine.n_legs,):
            raise FieldError("drive_forces", f"expected {self.machine.n_legs} values, got shape {forces.shape}")
        x0, x1, x2, v0, v1, v2, q, rows, qdot, jdv, code, leg = semi_implicit_step_kernel(
            self.machine.bars, self.machine.twist_columns, x[0], x[1], x[2], xdot[0], xdot[1], xdot[2],
            forces, wrench[0], wrench[1], wrench[2], h, substeps, *self._mass_args)
        if code == STEP_SINGULAR_MASS:
            raise np.linalg.LinAlgError("singular 3x3 system")
        if code != B.VT_OK:
            self.machine.raise_velocity_terms_error(code, leg, [x0, x1, x2])
        return [x0, x1, x2], [v0, v1, v2], (q.tolist(), rows.tolist(), qdot.tolist(), jdv.tolist())

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


def holding_forces(dynamics, rows, x) -> np.ndarray:
    """The drive forces of minimum 2-norm that hold the platform still at x: the
    static wrench H(x, 0) (``dynamics.static_forces``, either model) distributed by the
    pseudo-inverse (ARCHI §3.4, §4.4.1); ``rows``: J_m at x (of the drives that act).
    Raises DistributionError where J_m has not full rank."""
    return min_two_norm(rows, dynamics.static_forces(x))


def dynamic_model(config):
    """The dynamic model of a machine configuration (its ``dynamics`` section):
    ``rigid_body.StrutDynamics`` for a platform on struts in SE(3), ``DynamicModel``
    (ARCHI §3.4) for the rail machines. Both give ``static_forces(x)``, the platform
    wrench that holds x still."""
    if config.dynamics is None:
        raise ValueError(f"machine {config.name!r}: no 'dynamics' section")
    if isinstance(config.dynamics, RigidBodyParameters):
        return StrutDynamics(config.model, config.dynamics)
    return DynamicModel(config.model, config.dynamics)


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:], float64[:], float64, float64, float64, "
        "float64, float64, float64)")
def _mass_terms_kernel(rows, qdot, jdv, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2):
    """(A_00, A_01, A_02, A_11, A_12, A_22, H_0, H_1, H_2) from J_m (rows), qdot = J_m xdot
    and Jdot_m xdot: A = J^T M_d J + M_n, H = J^T (M_d Jdot xdot + k qdot - M_d g_u) - M_n g
    (module docstring; ``pg`` is M_n g, ``dg`` the carriages' weights along their rails)."""
    a00, a11, a22 = mn0, mn1, mn2
    a01 = a02 = a12 = 0.0
    h0, h1, h2 = -pg0, -pg1, -pg2
    for i in range(rows.shape[0]):
        j0, j1, j2, mi = rows[i, 0], rows[i, 1], rows[i, 2], md[i]
        a00 += mi * j0 * j0
        a01 += mi * j0 * j1
        a02 += mi * j0 * j2
        a11 += mi * j1 * j1
        a12 += mi * j1 * j2
        a22 += mi * j2 * j2
        c = mi * jdv[i] + k[i] * qdot[i] - dg[i]        # per-drive force not producing acceleration
        h0 += j0 * c
        h1 += j1 * c
        h2 += j2 * c
    return a00, a01, a02, a11, a12, a22, h0, h1, h2


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64, float64, float64, float64[:], float64[:], "
        "float64[:], float64, float64, float64, float64, float64, float64)")
def forward_acceleration_kernel(rows, qdot, jdv, forces, w0, w1, w2, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2):
    """xddot = A^-1 (J^T f + w - H) (ARCHI §3.4) from J_m (rows), qdot and Jdot_m xdot:
    A and H by :func:`_mass_terms_kernel`, Cramer's rule (planar.solve3_kernel).
    Returns (xddot_0, xddot_1, xddot_2, solvable)."""
    a00, a01, a02, a11, a12, a22, h0, h1, h2 = _mass_terms_kernel(rows, qdot, jdv, md, k, dg, mn0, mn1, mn2,
                                                                  pg0, pg1, pg2)
    r0, r1, r2 = w0 - h0, w1 - h1, w2 - h2
    for i in range(rows.shape[0]):
        f = forces[i]
        r0 += rows[i, 0] * f
        r1 += rows[i, 1] * f
        r2 += rows[i, 2] * f
    return solve3_kernel(a00, a01, a02, a01, a11, a12, a02, a12, a22, r0, r1, r2)


@kernel("(float64[:, :], int64[:], float64, float64, float64, float64, float64, float64, float64[:], float64, "
        "float64, float64, float64, int64, float64[:], float64[:], float64[:], float64, float64, float64, float64, "
        "float64, float64)")
def semi_implicit_step_kernel(bars, columns, x0, x1, x2, v0, v1, v2, forces, w0, w1, w2, h, substeps,
                              md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2):
    """DynamicModel.semi_implicit_step: per substep, the velocity terms at (x, v),
    xddot (:func:`forward_acceleration_kernel`), v += h xddot, x += h v; then the
    velocity terms at the state reached. Returns (x, v, q, J_m, q', J_m' x', code, leg): code bars.VT_OK, a
    velocity-terms code with x the pose where it failed, or STEP_SINGULAR_MASS."""
    m = forces.shape[0]
    q, rows, qd, jdv, no_rates = np.empty(m), np.empty((m, 3)), np.empty(m), np.empty(m), np.empty((0, 3))
    for _ in range(substeps):
        px, py, pz, r, t = B.task_pose_twist(columns, x0, x1, x2, v0, v1, v2)
        code, leg = B.rail_velocity_terms_into(bars, px, py, pz, r, t, columns, q, rows, qd, jdv, no_rates)
        if code != B.VT_OK:
            return x0, x1, x2, v0, v1, v2, q, rows, qd, jdv, code, leg
        acc0, acc1, acc2, ok = forward_acceleration_kernel(rows, qd, jdv, forces, w0, w1, w2, md, k, dg,
                                                           mn0, mn1, mn2, pg0, pg1, pg2)
        if not ok:
            return x0, x1, x2, v0, v1, v2, q, rows, qd, jdv, STEP_SINGULAR_MASS, -1
        v0, v1, v2 = v0 + h * acc0, v1 + h * acc1, v2 + h * acc2
        x0, x1, x2 = x0 + h * v0, x1 + h * v1, x2 + h * v2
    px, py, pz, r, t = B.task_pose_twist(columns, x0, x1, x2, v0, v1, v2)
    code, leg = B.rail_velocity_terms_into(bars, px, py, pz, r, t, columns, q, rows, qd, jdv, no_rates)
    return x0, x1, x2, v0, v1, v2, q, rows, qd, jdv, code, leg


@kernel("(float64[:, :], int64[:], float64, float64, float64, float64[:], float64[:], float64[:], float64[:], "
        "float64, float64, float64, float64, float64, float64)")
def _measured_state_kernel(bars, columns, x0, x1, x2, qdot, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2):
    """DynamicModel.measured_state: J_m at x (velocity terms at zero velocity), v by least
    squares from qdot, then the velocity terms at (x, v) and A, H there. Returns (J_m,
    v0, v1, v2, A's 6 entries, H, code, leg)."""
    m = qdot.shape[0]
    q, rows, qd, jdv, no_rates = np.empty(m), np.empty((m, 3)), np.empty(m), np.empty(m), np.empty((0, 3))
    px, py, pz, r, t = B.task_pose_twist(columns, x0, x1, x2, 0.0, 0.0, 0.0)
    code, leg = B.rail_velocity_terms_into(bars, px, py, pz, r, t, columns, q, rows, qd, jdv, no_rates)
    if code != B.VT_OK:
        return rows, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, code, leg
    v0, v1, v2, ok = least_squares_kernel(rows, qdot)
    if not ok:
        return rows, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, VT_LEAST_SQUARES_SINGULAR, -1
    px, py, pz, r, t = B.task_pose_twist(columns, x0, x1, x2, v0, v1, v2)       # the same pose, the twist found
    code, leg = B.rail_velocity_terms_into(bars, px, py, pz, r, t, columns, q, rows, qd, jdv, no_rates)
    a00, a01, a02, a11, a12, a22, h0, h1, h2 = _mass_terms_kernel(rows, qd, jdv, md, k, dg, mn0, mn1, mn2,
                                                                  pg0, pg1, pg2)
    return rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, code, leg


def _measured_state(rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2) -> tuple:
    """(A as 3 rows, H, J_m, v) of _measured_state_kernel's outputs (A symmetric: its 6 entries)."""
    return ((a00, a01, a02), (a01, a11, a12), (a02, a12, a22)), (h0, h1, h2), rows, (v0, v1, v2)


_STATE_TAIL = ("float64[:], float64[:], float64[:], float64[:], float64, float64, float64, float64, float64, "
               "float64)")      # after the columns (int64[:]): qdot, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2


@kernel("(float64[:, :], int64[:, :], float64[:], float64[:], float64, float64, float64, int64[:], " + _STATE_TAIL)
def planar_encoder_state_kernel(bars, pairs, sides, q, ref_x, ref_y, ref_th, columns, qdot, md, k, dg, mn0, mn1, mn2,
                                pg0, pg1, pg2):
    """A planar rail machine's encoder state in one call (DynamicModel.encoder_state):
    the forward kinematics of q (planar.forward_kinematics_kernel, Newton from the
    reference pose), then _measured_state_kernel there. Returns (x, y, theta, solved,
    then _measured_state_kernel's outputs)."""
    x, y, th, code, _, _, _, _, _ = forward_kinematics_kernel(bars, pairs, sides, q, ref_x, ref_y, ref_th, FK_TOL,
                                                              FK_MAX_ITERATIONS)
    if code != FK_CONVERGED:
        return (x, y, th, False, np.empty((0, 3)), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                B.VT_OK, -1)
    rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, vt, leg = _measured_state_kernel(
        bars, columns, x, y, th, qdot, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2)
    return x, y, th, True, rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, vt, leg


@kernel("(float64[:, :], float64, float64[:], int64[:], " + _STATE_TAIL)
def spheres_encoder_state_kernel(bars, side, q, columns, qdot, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2):
    """:func:`planar_encoder_state_kernel` of a three-rail translating machine: the
    three spheres' intersection (bars.three_rail_forward_kinematics_kernel), then
    _measured_state_kernel there."""
    x, y, z, code, _ = B.three_rail_forward_kinematics_kernel(bars, q[0], q[1], q[2], side)
    if code != B.TRI_OK:
        return (x, y, z, False, np.empty((0, 3)), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                B.VT_OK, -1)
    rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, vt, leg = _measured_state_kernel(
        bars, columns, x, y, z, qdot, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2)
    return x, y, z, True, rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, vt, leg


@kernel()
def rail_encoder_state_kernel(spheres, bars, pairs, sides, side, q, ref_x, ref_y, ref_th, columns, qdot, md, k, dg,
                              mn0, mn1, mn2, pg0, pg1, pg2):
    """:func:`planar_encoder_state_kernel` or, ``spheres``, :func:`spheres_encoder_state_kernel`,
    for a compiled caller that serves both (the arguments of the other one unused):
    DynamicModel.encoder_state_inputs gives what follows q."""
    if spheres:
        return spheres_encoder_state_kernel(bars, side, q, columns, qdot, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2)
    return planar_encoder_state_kernel(bars, pairs, sides, q, ref_x, ref_y, ref_th, columns, qdot, md, k, dg, mn0,
                                       mn1, mn2, pg0, pg1, pg2)


# the per-cycle calls, without the dispatcher's typing of every argument (jit.direct_call:
# DynamicModel._encoder_state makes each argument with the declared type)
_planar_encoder_state = direct_call(planar_encoder_state_kernel)
_spheres_encoder_state = direct_call(spheres_encoder_state_kernel)
