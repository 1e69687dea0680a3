"""The forward kinematics of three-axis translational PKMs (``rails.RailMachine``
with the task space POSITION): three prismatic actuators, parallelogram legs.

Covers the linear Delta of MoM3 (parallel rails) and the Orthoglide (orthogonal
rails). The parallelograms keep the platform orientation constant, so the pose is
the tool-centre position p (m).

Model (Orthoglide §3.1-3.2): carriage B_i = o_i + rho_i e_i on rail i (unit e_i),
platform joint C_i = p + c_i, |C_i - B_i| = L_i. Inverse kinematics in closed form
with the assembly branch sigma_i:
    w_i = p + c_i - o_i,  rho_i = e_i . w_i + sigma_i sqrt(L_i^2 - |w_i|^2 + (e_i . w_i)^2).
Velocity (Orthoglide eq. 3-4): A pdot = B rhodot with
    A = [(c_i - b_i)^T] (parallel Jacobian),  B = diag((c_i - b_i)^T e_i) (serial Jacobian),
so the inverse Jacobian is J^-1 = B^-1 A (eq. 8), which we call J_m (rhodot = J_m pdot).
Velocity transmission factors (§4.3): psi_i = 1/sqrt(lambda_i) with lambda_i the
eigenvalues of (J J^T)^-1, i.e. the singular values of J = J_m^-1.

Each leg is one bar of the bar model (``bars``, MACHINE_MODEL.md: a parallelogram
with equal bars closes like its centre line), the platform translating (R = I,
twist columns vx, vy, vz): a ``rails.RailMachine``, whose IK, J_m, velocity terms,
batches and analyses (A, B, psi, the parallel-singularity measure) are every rail
machine's; the forward kinematics here (``ThreeSpheresFK``, "three_spheres" in
``rails.FORWARD_SOLVERS``: ``bars.three_rail_forward_kinematics_kernel``).
"""

from __future__ import annotations

import math

import numpy as np

from . import bars as B
from .errors import FieldError, KinematicsError, SingularityError, UnreachablePoseError
from .machine import ForwardKinematicsResult
from .task_space import POSITION
from .validation import finite_array, finite_floats


class ThreeSpheresFK:
    """The forward kinematics of a three-rail translating machine
    (``rails.FORWARD_SOLVERS`` "three_spheres"): the intersection of three spheres
    (centres B_i - c_i, radii L_i) on the working-mode side. Closed form, compiled
    (``bars.three_rail_forward_kinematics_kernel``)."""

    def __init__(self, machine):
        if machine.task_space is not POSITION or machine.n_legs != 3:
            raise FieldError("forward", f"three_spheres solves a translating machine of exactly 3 legs, got "
                                        f"{machine.n_legs} legs in {machine.task_space.name} coordinates")
        self.machine, self.bars = machine, machine.bars
        # Forward branch: the platform lies on one side of the plane through the three
        # sphere centres; that side only changes through a parallel singularity
        # (Orthoglide §3.3), so it is the working mode.
        home = machine.home
        rho = machine.inverse_kinematics(home, check_limits=False)
        centres = machine.rail_origins + rho[:, None] * machine.rail_directions - self.bars[:, B.COL_B:B.COL_B + 3]
        normal = np.cross(centres[1] - centres[0], centres[2] - centres[0])
        self.side = math.copysign(1.0, float(normal @ (home - centres[0])))

    def solve(self, rho, guess=None) -> ForwardKinematicsResult:
        """The position of drive positions ``rho`` (``guess``: unused, the closed form
        needs none) as a result: not converged, with the reason, where :meth:`floats`
        raises."""
        r = finite_floats(rho, 3, "rho")
        try:
            return ForwardKinematicsResult(np.array(self.floats(r)), True, 0, 0.0)
        except KinematicsError as exc:
            return ForwardKinematicsResult(np.full(3, np.nan), False, 0, math.nan, str(exc))

    def floats(self, rho, guess=None) -> tuple[float, float, float]:
        """The position of ``rho`` (3 floats, finiteness unchecked: the caller
        checked it) as a tuple. Raises UnreachablePoseError when the spheres do not
        meet or when the point found needs a leg on its other assembly branch,
        SingularityError when the centres are collinear."""
        if len(rho) != 3:
            raise FieldError("rho", f"expected 3 actuator positions, got {len(rho)}")
        px, py, pz, code, leg = B.three_rail_forward_kinematics_kernel(self.bars, float(rho[0]), float(rho[1]),
                                                                       float(rho[2]), self.side)
        if code == B.TRI_OK:
            return px, py, pz
        r = [float(v) for v in rho]
        if code == B.TRI_COLLINEAR:
            raise SingularityError(f"actuator positions {r} m: the three sphere centres are collinear "
                                   "(the platform position is not determined)")
        if code == B.TRI_NOT_MEETING:
            raise UnreachablePoseError(f"actuator positions {r} m cannot be assembled: the legs do not meet")
        raise UnreachablePoseError(f"actuator positions {r} m assemble only with leg {self.machine.leg_names[leg]} "
                                   f"on its other branch (assembly {int(self.bars[leg, B.COL_BRANCH]):+d})")

    def batch(self, rho, guesses=None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`floats` of rho (N, 3), the per-pose kernel on every row: (positions,
        ok mask); NaN rows where the legs do not meet or a leg would be on its other
        branch (``guesses``: unused)."""
        rho = np.ascontiguousarray(finite_array(rho, "rho", (-1, 3)))
        p, ok = np.empty(rho.shape), np.empty(rho.shape[0], dtype=bool)
        B.three_rail_forward_kinematics_batch_kernel(self.bars, rho, self.side, p, ok)
        return p, ok


def unit_rows_determinant(rows) -> np.ndarray:
    """|det| of the rows normalised to unit length (the last two axes): the parallel
    singularity measure of Orthoglide §3.3 for the leg vectors, or for any rows
    parallel to them (J_m's)."""
    rows = np.asarray(rows, dtype=float)
    return np.abs(np.linalg.det(rows / np.linalg.norm(rows, axis=-1, keepdims=True)))
