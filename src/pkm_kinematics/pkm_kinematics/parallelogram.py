"""A Delta on rails with its parallelograms as bars (``bars``; MACHINE_MODEL.md):
each leg's carriage carries two bars of a parallelogram to the platform, so a leg is
two bars on one actuator. With equal bars the platform only translates (the
Orthoglide's and the Delta's design); with unequal bars, MoM3 §4.1's "imperfect
case", it also turns: the parasitic rotation, which the drive encoders cannot see
and the Gough metrology can (MoM3 §3-4: M = 6).

Task coordinates: the platform position p (3). The rotation R follows from the bars
(``inverse_kinematics_full``: Newton on the six bar misfits over (w, q) with p
held), the actuators from both. Forward kinematics: Newton on the six bars over
(p, R). J_m by implicit differentiation of the six closure equations:
[e_k/|e_k| . p' + ((R b_k) x e_k)/|e_k| . w - (e_k . u_k)/|e_k| q'_j = 0] solved for
(w, q') given p'.

Bar k of leg i (s = -1, +1): base joint a_i + s h t_i on rail u_i (actuator i),
platform joint b_i + s h t_i, length L_i + delta_{i,s}; t_i = u_i x b_i / |u_i x b_i|
(across the leg: tangential on a Delta), h the parallelogram's half-width.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import bars as B
from .distribution import gram_condition
from .errors import FieldError, JointLimitError, KinematicsError, SingularityError, UnreachablePoseError
from .measures import condition_numbers, cube_grid
from .rotations import log_so3
from .task_space import POSITION


class ParasiticPose(NamedTuple):
    """The actuator values and the rotation a platform position takes (IK)."""
    q: np.ndarray
    rotation: np.ndarray
    iterations: int


class ParallelogramMachine:
    """Three rails, each carrying a parallelogram of two bars (module doc). ``legs``:
    ``rails.RailLeg`` records (name, rail_origin, rail_direction, link_length,
    platform_point: the platform offset, assembly, joint_limits)."""

    def __init__(self, name: str, legs, half_width_m: float, bar_length_errors_m, home, workspace: dict,
                 description: str = ""):
        if len(legs) != 3:
            raise FieldError("legs", f"a parallelogram Delta has exactly 3 legs, got {len(legs)}")
        if not half_width_m > 0.0:
            raise FieldError("half_width", f"must be > 0 m, got {half_width_m}")
        errors = np.asarray(bar_length_errors_m, dtype=float).reshape(3, 2)
        self.name, self.description, self.workspace = name, description, workspace
        self.legs = list(legs)
        self.leg_names = [leg.name for leg in legs]
        self.n_legs, self.task_dof, self.spatiality = 3, 3, 3
        self.task_space = POSITION
        self.half_width_m, self.bar_length_errors_m = float(half_width_m), errors
        self.joint_lower = np.array([leg.joint_limits[0] for leg in legs], dtype=float)
        self.joint_upper = np.array([leg.joint_limits[1] for leg in legs], dtype=float)
        base, platform, rail, length, actuator, branch = [], [], [], [], [], []
        for i, leg in enumerate(legs):
            u = np.asarray(leg.rail_direction, dtype=float)
            u = u / np.linalg.norm(u)
            b = np.asarray(leg.platform_point, dtype=float)
            across = np.cross(u, b)
            if not np.linalg.norm(across) > 1e-9:
                raise ValueError(f"legs[{i}]: the platform offset is along the rail: no direction across the leg")
            t = across / np.linalg.norm(across)
            for s, delta in zip((-1.0, 1.0), errors[i]):
                base.append(np.asarray(leg.rail_origin, dtype=float) + s * half_width_m * t)
                platform.append(b + s * half_width_m * t)
                rail.append(u)
                length.append(leg.link_length + delta)
                actuator.append(i)
                branch.append(float(leg.assembly))
        self.bars = B.bar_rows(base, platform, actuator, B.RAIL, rail=rail, length=length, branch=branch)
        self._home = np.asarray(home, dtype=float)
        self._home_rotation = self.inverse_kinematics_full(self._home).rotation

    @property
    def home(self) -> np.ndarray:
        return self._home.copy()

    # -------------------------------------------------------------- inverse
    def inverse_kinematics_full(self, position, tol_m: float = 1e-13, max_iterations: int = 20) -> ParasiticPose:
        """The actuators and the platform's rotation at ``position``
        (``bars.inverse_kinematics_parasitic_kernel``, from R = I)."""
        p = np.ascontiguousarray(position, dtype=float).reshape(3)
        rot, q = np.eye(3).reshape(9).copy(), np.empty(3)
        code, iterations, misfit = B.inverse_kinematics_parasitic_kernel(self.bars, p, rot, q, tol_m, max_iterations)
        if code == B.IK_UNREACHABLE + 10:
            raise UnreachablePoseError(f"{self.name}: a leg cannot reach p = {p.tolist()}")
        if code != B.FK_CONVERGED:
            raise KinematicsError(f"{self.name}: the bars do not close at p = {p.tolist()} "
                                  f"(code {code}, misfit {misfit:.3g} m after {iterations} iterations)")
        return ParasiticPose(q, rot.reshape(3, 3), int(iterations))

    def inverse_kinematics(self, position, check_limits: bool = True) -> np.ndarray:
        q = self.inverse_kinematics_full(position).q
        if check_limits:
            self.check_joint_limits(q)
        return q

    def check_joint_limits(self, q) -> None:
        """Raise JointLimitError naming the first drive of ``q`` outside its limits."""
        q = np.asarray(q, dtype=float)
        for k in np.flatnonzero(~((q >= self.joint_lower) & (q <= self.joint_upper))):
            raise JointLimitError(f"{self.leg_names[k]}: {q[k]:.6f} m outside its limits "
                                  f"[{self.joint_lower[k]:.6f}, {self.joint_upper[k]:.6f}] m")

    def inverse_kinematics_batch(self, positions) -> tuple[np.ndarray, np.ndarray]:
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        q, ok = np.full((len(positions), 3), np.nan), np.zeros(len(positions), dtype=bool)
        for k, p in enumerate(positions):
            try:
                q[k], ok[k] = self.inverse_kinematics_full(p).q, True
            except KinematicsError:
                pass
        return q, ok

    def within_joint_limits(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.joint_lower) & (q <= self.joint_upper), axis=-1)

    def parasitic_rotation(self, position) -> np.ndarray:
        """The rotation vector (rad) the platform takes at ``position``: zero with
        equal bars."""
        return log_so3(self.inverse_kinematics_full(position).rotation)

    # -------------------------------------------------------------- forward
    def forward_kinematics_full(self, q, guess=None, tol_m: float = 1e-13, max_iterations: int = 30):
        """(p, R) of the actuator values ``q`` (Newton on the six bars), from ``guess``
        (a position; default home, with the home's rotation)."""
        q = np.ascontiguousarray(q, dtype=float).reshape(3)
        p = np.array(self._home if guess is None else guess, dtype=float)
        rot = self._home_rotation.reshape(9).copy()
        code, iterations, misfit = B.forward_kinematics_kernel(self.bars, q, p, rot, tol_m, max_iterations, 1.0)
        if code != B.FK_CONVERGED:
            raise KinematicsError(f"{self.name}: forward kinematics of q = {q.tolist()} did not converge "
                                  f"(code {code}, misfit {misfit:.3g} m)")
        return p, rot.reshape(3, 3)

    def forward_kinematics_floats(self, q, guess=None) -> tuple:
        return tuple(self.forward_kinematics_full(q, guess)[0].tolist())

    # ------------------------------------------------------------ Jacobians
    def jacobian(self, position) -> np.ndarray:
        """J_m (3, 3): q' = J_m p' with the rotation following the bars (module doc)."""
        pose = self.inverse_kinematics_full(position)
        p = np.ascontiguousarray(position, dtype=float).reshape(3)
        r = tuple(pose.rotation.reshape(9))
        closure, rows = np.empty((6, 6)), np.empty((6, 6))
        if not (B.rail_closure_rows_into(self.bars, p[0], p[1], p[2], r, pose.q, closure)
                and B.unit_pose_jacobian_into(self.bars, p[0], p[1], p[2], r, pose.q, rows)):
            raise SingularityError(f"a bar has zero length at p = {p.tolist()}")
        try:
            solved = -np.linalg.solve(closure, rows[:, :3])       # (w, q') per unit p'
        except np.linalg.LinAlgError:
            raise SingularityError(f"the bars' closure is singular at p = {p.tolist()}") from None
        return solved[3:]

    def jacobian_batch(self, positions) -> np.ndarray:
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        out = np.full((len(positions), 3, 3), np.nan)
        for k, p in enumerate(positions):
            try:
                out[k] = self.jacobian(p)
            except KinematicsError:
                pass
        return out

    # the task coordinates' rates are the twist here: q' = J_m x'
    task_jacobian_batch = jacobian_batch

    def condition_number(self, position) -> float:
        return float(np.linalg.cond(self.jacobian(position)))

    def rows_condition(self, jac) -> float:
        """2-norm condition number of given rows of J_m (n' x 3: a sub-machine's, the
        drives still active), closed form (distribution.gram_condition); inf when
        singular."""
        return gram_condition(jac)

    def condition_number_batch(self, positions) -> np.ndarray:
        return condition_numbers(self.jacobian_batch(positions))

    def workspace_grid(self, points_per_axis: int = 11, theta_points: int = 13) -> np.ndarray:
        """A regular grid over the workspace cube: (N, 3) positions."""
        return cube_grid(self.workspace["center"], self.workspace["size"], points_per_axis)


def tilt_urad(rotation_vector) -> float:
    """|rotation vector| in microradians."""
    return 1e6 * float(math.sqrt(float(np.dot(rotation_vector, rotation_vector))))


__all__ = ["ParallelogramMachine", "ParasiticPose", "tilt_urad"]
