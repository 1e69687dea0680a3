"""Strut machines: the Gough-Stewart hexapod (6 actuated struts, 6 DOF; LinuxCNC's
genhexkins) and the redundantly actuated hexapods (more struts than 6) as
configurations of the bar model (``bars``; ../shared/MACHINE_MODEL.md).

Task coordinates x = (x, y, z, a, b, c): the platform point in the base frame (m)
and the rotations about the base x, y, z axes (rad), R = Rz(c) Ry(b) Rx(a), the
convention of genhexkins (pmRpyMatConvert) and of G-code's A, B, C words. Velocities
are twists t = (v, w), w in the base frame; ``rate_matrix`` maps (a', b', c') to w.

Per pose (Pinocchio's constant model, per-stream data): ``StrutMachine`` is the
constant model; ``StrutFK`` keeps the warm start of one stream of readings.
Everything calls the compiled kernels of ``bars``.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from . import bars as B
from .errors import FieldError, JointLimitError, KinematicsError, SingularityError
from .jit import direct_call, kernel
from .rotations import rate_matrix, rate_matrix_kernel, rotation_from_rpy, rpy_kernel, rpy_rotation_kernel
from .task_space import SPATIAL, task_pose


class FKCode(IntEnum):
    """How a forward kinematics solve ended (``bars.forward_kinematics_kernel``)."""
    CONVERGED = B.FK_CONVERGED
    NO_CONVERGENCE = B.FK_NO_CONVERGENCE
    DIVERGED = B.FK_DIVERGED
    SINGULAR = B.FK_SINGULAR
    STALLED = B.FK_STALLED


class StrutFKResult(NamedTuple):
    """A forward kinematics solve: the pose (task coordinates and (p, R)), how it
    ended, its iterations, and the misfit left (m, root sum of squares of
    |e_k| - q_k: zero for consistent struts; with more struts than 6 it measures how
    far the strut readings are from any pose)."""
    code: FKCode
    position: np.ndarray
    rotation: np.ndarray
    iterations: int
    misfit_m: float

    @property
    def ok(self) -> bool:
        return self.code == FKCode.CONVERGED

    @property
    def x(self) -> np.ndarray:
        """The task coordinates (x, y, z, a, b, c) of the pose (computed on demand: a
        per-cycle caller that uses (p, R) does not pay for the angles)."""
        return StrutMachine.task_coordinates(self.position, self.rotation)


_CODES = {int(c): c for c in FKCode}
# a controller's solve of its readings each cycle (forward_kinematics_floats,
# rigid_body.strut_encoder_state_kernel): tolerance m, iterations, divergence limit m
CYCLE_FK = (1e-12, 30, 1.0)
_FLOAT64 = np.dtype(np.float64)
# StrutFK.solve makes every argument itself (the readings made float64 there), with the declared types
_warm_solve = direct_call(B.forward_kinematics_warm_kernel)


class StrutMachine:
    """A platform on n >= 6 actuated struts between base joints a_k and platform
    joints b_k (strut k = actuator k). Constant after construction."""

    def __init__(self, name: str, strut_names, base, platform, joint_limits, home, workspace: dict,
                 description: str = "", characteristic_length_m: float | None = None):
        self.name, self.description = name, description
        self.leg_names = [str(s) for s in strut_names]
        self.n_legs = len(self.leg_names)
        base, platform = np.asarray(base, dtype=float), np.asarray(platform, dtype=float)
        self.bars = B.bar_rows(base, platform, actuator=np.arange(self.n_legs), kind=B.STRUT)
        limits = np.asarray(joint_limits, dtype=float).reshape(self.n_legs, 2)
        self.joint_lower, self.joint_upper = limits[:, 0].copy(), limits[:, 1].copy()
        self._home = np.asarray(home, dtype=float)
        self.workspace = workspace
        # for the condition number: rotations weighted by the platform's size, so that
        # J is dimensionless (the rotation columns are metres per radian)
        # (1 m where every platform joint is at the centre: nothing holds the rotation then)
        self.characteristic_length_m = float(characteristic_length_m or
                                              np.max(np.linalg.norm(platform, axis=1)) or 1.0)
        self.task_dof = self.spatiality = 6     # x, y, z, a, b, c: SE(3)
        self.task_space = SPATIAL

    # ------------------------------------------------------------------ poses
    @property
    def home(self) -> np.ndarray:
        return self._home.copy()

    @property
    def base_joints(self) -> np.ndarray:
        return self.bars[:, B.COL_A:B.COL_A + 3].copy()

    @property
    def platform_joints(self) -> np.ndarray:
        return self.bars[:, B.COL_B:B.COL_B + 3].copy()

    @staticmethod
    def pose(x) -> tuple[np.ndarray, np.ndarray]:
        """(p, R) of task coordinates x = (x, y, z, a, b, c)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (6,):
            raise FieldError("x", f"expected 6 task coordinates (x, y, z, a, b, c), got shape {x.shape}")
        return x[:3].copy(), rotation_from_rpy(x[3], x[4], x[5])

    @staticmethod
    def task_coordinates(position, rotation) -> np.ndarray:
        """x = (x, y, z, a, b, c) of the pose (p, R); |b| < pi/2 (``task_space.task_pose``)."""
        return task_pose(SPATIAL, position, rotation)

    def leg_joints(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Each strut's base and platform joint (n, 3) each, for drawing."""
        p, rot = self.pose(x)
        return self.base_joints, p + self.platform_joints @ rot.T

    # -------------------------------------------------------------- inverse
    def strut_lengths(self, position, rotation) -> np.ndarray:
        """IK of the pose (p, R): q_k = |p + R b_k - a_k|."""
        q = np.empty(self.n_legs)
        B.inverse_kinematics_into(self.bars, np.asarray(position, dtype=float),
                                  np.ascontiguousarray(rotation, dtype=float).reshape(9), q)
        return q

    def inverse_kinematics(self, x, check_limits: bool = True) -> np.ndarray:
        """Strut lengths of task coordinates x; JointLimitError naming the strut
        outside its limits."""
        q = self.strut_lengths(*self.pose(x))
        if check_limits:
            self.check_joint_limits(q, x)
        return q

    def check_joint_limits(self, q, x=None) -> None:
        """Raise JointLimitError naming the first strut of ``q`` outside its limits
        (and the pose ``x``, when given)."""
        q = np.asarray(q, dtype=float)
        for k in np.flatnonzero(~((q >= self.joint_lower) & (q <= self.joint_upper))):
            at = "" if x is None else f" at x = {np.array2string(np.asarray(x, dtype=float), precision=6)}"
            raise JointLimitError(f"{self.leg_names[k]}: {q[k]:.6f} m outside its limits "
                                  f"[{self.joint_lower[k]:.6f}, {self.joint_upper[k]:.6f}] m{at}")

    def inverse_kinematics_batch(self, xs) -> tuple[np.ndarray, np.ndarray]:
        """Strut lengths of poses (N, 6) and whether each assembles (every length
        finite: a strut reaches any pose; the limits are ``within_joint_limits``', as
        on the rail machines)."""
        xs = np.asarray(xs, dtype=float).reshape(-1, 6)
        q = np.array([self.strut_lengths(*self.pose(x)) for x in xs]).reshape(len(xs), self.n_legs)
        return q, np.isfinite(q).all(axis=1)

    def within_joint_limits(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.joint_lower) & (q <= self.joint_upper), axis=-1)

    # -------------------------------------------------------------- forward
    def forward_kinematics(self, q, guess=None, tol_m: float = 1e-12, max_iterations: int = 30,
                           divergence_limit_m: float = 1.0) -> StrutFKResult:
        """The pose of strut lengths ``q`` nearest ``guess`` (task coordinates;
        default: home), Newton / Gauss-Newton (``bars.forward_kinematics_kernel``)."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_legs,) or not np.isfinite(q).all() or not (q > 0.0).all():
            raise FieldError("q", f"expected {self.n_legs} finite positive strut lengths, got {q}")
        p, rot = self.pose(self._home if guess is None else guess)
        return self.solve_from(q, p, rot.reshape(9).copy(), tol_m, max_iterations, divergence_limit_m)

    def solve_from(self, q, p, rot, tol_m, max_iterations, divergence_limit_m) -> StrutFKResult:
        """The kernel's solve from the pose (p (3,), rot (9,) row-major), both updated
        in place (``StrutFK`` keeps them as its warm start)."""
        code, iterations, misfit = B.forward_kinematics_kernel(self.bars, q, p, rot, tol_m, max_iterations,
                                                               divergence_limit_m)
        return StrutFKResult(_CODES[code], p.copy(), rot.reshape(3, 3).copy(), iterations, misfit)

    def forward_kinematics_floats(self, q, guess=None) -> tuple:
        """:meth:`forward_kinematics`'s task coordinates as a tuple; KinematicsError
        naming how the solve ended when it fails."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_legs,) or not np.isfinite(q).all() or not (q > 0.0).all():
            raise FieldError("q", f"expected {self.n_legs} finite positive strut lengths, got {q}")
        g = self._home if guess is None else guess
        code, iterations, misfit, x = task_forward_kinematics_kernel(self.bars, q, tuple(float(v) for v in g[:6]),
                                                                     *CYCLE_FK)
        if code != B.FK_CONVERGED:
            raise KinematicsError(f"forward kinematics of q = {q.tolist()}: {_CODES[code].name.lower()} "
                                  f"after {iterations} iterations (misfit {misfit:.3g} m)")
        return x

    # ------------------------------------------------------------- workspace
    def workspace_grid(self, points_per_axis: int = 11, angle_points: int = 3) -> np.ndarray:
        """(N, 6) poses: a regular grid over the workspace box, each point at every
        combination of the rotations' extremes and zero (``angle_points`` values per
        rotation, at most 3: a full grid in six dimensions is too large to sweep)."""
        ws = self.workspace
        lo, hi = ws["center"] - ws["half_size"], ws["center"] + ws["half_size"]
        k = max(1, min(int(angle_points), 3))
        axes = [np.linspace(a, b, points_per_axis) for a, b in zip(lo, hi)]
        axes += [np.radians(np.linspace(-r, r, k) if k > 1 else np.zeros(1)) + h
                 for r, h in zip(ws["abc_half_range_deg"], self._home[3:])]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 6)

    def jacobian_batch(self, poses) -> np.ndarray:
        """J_m at poses (N, 6): (N, n, 6)."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 6)
        return np.array([self.jacobian(x) for x in poses]).reshape(len(poses), self.n_legs, 6)

    def task_jacobian_batch(self, poses) -> np.ndarray:
        """:meth:`task_jacobian` at poses (N, 6): (N, n, 6), in one compiled pass
        (``pose_jacobians_into``: a planner's validation asks ~10^5 poses)."""
        poses = np.ascontiguousarray(np.asarray(poses, dtype=float).reshape(-1, 6))
        rows, rates = np.empty((len(poses), self.n_legs, 6)), np.empty((len(poses), 3, 3))
        bad = pose_jacobians_into(self.bars, poses, rows, rates)
        if bad >= 0:
            raise SingularityError(f"a strut has zero length at x = {poses[bad]}")
        rows[:, :, 3:] = np.matmul(rows[:, :, 3:], rates)
        return rows

    def condition_number_batch(self, poses) -> np.ndarray:
        """:meth:`condition_number` at poses (N, 6)."""
        return np.array([self.condition_number(x) for x in np.asarray(poses, dtype=float).reshape(-1, 6)])

    # ------------------------------------------------------------ Jacobians
    def jacobian(self, x) -> np.ndarray:
        """J_m (n, 6): q' = J_m t for the platform twist t = (v, w) (MoM3 eq. 2:
        rows [u_k, (R b_k) x u_k], u_k the unit vector of strut k)."""
        p, rot = self.pose(x)
        jac = np.empty((self.n_legs, 6))
        if not B.unit_pose_jacobian_into(self.bars, p[0], p[1], p[2], tuple(rot.reshape(9)),
                                         np.zeros(self.n_legs), jac):
            raise SingularityError(f"a strut has zero length at x = {x}")
        return jac

    def task_jacobian(self, x) -> np.ndarray:
        """q' = J x' for the task coordinates' rates (rotation rates through
        ``rate_matrix``; many poses: :meth:`task_jacobian_batch`)."""
        x = np.asarray(x, dtype=float)
        jac = self.jacobian(x)
        return np.hstack((jac[:, :3], jac[:, 3:] @ rate_matrix(*x[3:])))

    def jacobian_derivative(self, x, twist) -> np.ndarray:
        """dJ_m/dt along the twist t = (v, w): row k = [u', (R b)' x u + (R b) x u']
        (``bars.unit_row_rate``)."""
        p, rot = self.pose(x)
        out = np.empty((self.n_legs, 6))
        if not B.unit_pose_jacobian_derivative_into(self.bars, p[0], p[1], p[2], tuple(rot.reshape(9)),
                                                    np.zeros(self.n_legs), np.asarray(twist, dtype=float), out):
            raise SingularityError(f"a strut has zero length at x = {x}")
        return out

    def velocity_terms(self, x, twist) -> tuple[list, np.ndarray, list, list]:
        """(q, J_m, q' = J_m t, J_m' t) at the pose x moving with the twist t: what a
        joint-space controller needs of a task-space reference (the drive positions,
        velocities and the velocity-product part of their accelerations,
        q'' = J_m t' + J_m' t)."""
        p, rot = self.pose(x)
        t = np.asarray(twist, dtype=float).reshape(6)
        jac, jdot = self.jacobian(x), self.jacobian_derivative(x, t)
        return self.strut_lengths(p, rot).tolist(), jac, (jac @ t).tolist(), (jdot @ t).tolist()

    def wrench_map(self, x) -> np.ndarray:
        """J_m^T (6, n): the platform wrench (force, moment about p, base frame) of
        strut forces f, F = J_m^T f (virtual work: f . q' = F . t)."""
        return self.jacobian(x).T

    def internal_force_basis(self, x) -> np.ndarray:
        """An orthonormal basis (n, n - 6) of the strut forces that leave the platform's
        wrench unchanged (null space of J_m^T): empty for the 6-strut hexapod."""
        _, s, vt = np.linalg.svd(self.wrench_map(x))
        if s[-1] <= 1e-12 * s[0]:
            raise SingularityError(f"J_m loses rank at x = {x}: singular values {s}")
        return vt[6:].T.copy()

    def condition_number(self, x) -> float:
        """The condition number of J_m with its rotation columns divided by the
        characteristic length (the platform radius by default): a dimensionless J."""
        return self.rows_condition(self.jacobian(x))

    def rows_condition(self, jac) -> float:
        """:meth:`condition_number` of given rows of J_m (n' x 6: a sub-machine's, the
        drives still active); inf when they do not span the six DOF."""
        jac = np.array(jac, dtype=float)
        if jac.shape[0] < 6:
            return math.inf
        return weighted_condition_kernel(jac, self.characteristic_length_m)


@kernel("(float64[:, :], float64[:], UniTuple(float64, 6), float64, int64, float64)")
def task_forward_kinematics_kernel(bars, q, guess, tol_m, max_iterations, divergence_limit):
    """(code, iterations, misfit, x) of ``bars.forward_kinematics_kernel`` from and to
    task coordinates (x, y, z, a, b, c): one compiled call per cycle for a controller."""
    p = np.array([guess[0], guess[1], guess[2]])
    rot = np.array(rpy_rotation_kernel(guess[3], guess[4], guess[5]))
    code, iterations, misfit = B.forward_kinematics_kernel(bars, q, p, rot, tol_m, max_iterations, divergence_limit)
    a, b, c = rpy_kernel(rot[0], rot[3], rot[6], rot[7], rot[8])
    return code, iterations, misfit, (p[0], p[1], p[2], a, b, c)


@kernel("(float64[:, :], float64)")
def weighted_condition_kernel(jac, length):
    """cond(J W), W = diag(1, 1, 1, 1/L, 1/L, 1/L): sqrt of the extreme eigenvalues of
    W J^T J W (compiled: an SVD from Python costs ~80 us a cycle)."""
    j = jac.copy()
    j[:, 3:] /= length
    eig = np.linalg.eigvalsh(j.T @ j)
    if not eig[0] > 1e-300:
        return math.inf
    return math.sqrt(eig[-1] / eig[0])


class StrutFK:
    """Forward kinematics of one stream of strut readings, warm-started from the pose
    extrapolated from the last two found (``bars.forward_kinematics_warm_kernel``;
    the per-stream data beside a constant ``StrutMachine``)."""

    def __init__(self, machine: StrutMachine, tol_m: float = 1e-12, max_iterations: int = 30,
                 divergence_limit_m: float = 1.0):
        self.machine = machine
        self.tol_m, self.max_iterations, self.divergence_limit_m = tol_m, max_iterations, divergence_limit_m
        self._shape = (machine.n_legs,)
        self._state, self._flags = np.zeros(B.WARM_STATE_SIZE), np.zeros(1, dtype=np.int64)
        self.reset()

    def reset(self, x=None) -> None:
        """Start the stream again from the pose ``x`` (task coordinates; default home)."""
        p, rot = self.machine.pose(self.machine.home if x is None else x)
        self._state[B.WARM_P1:B.WARM_R1], self._state[B.WARM_R1:B.WARM_P0] = p, rot.reshape(9)
        self._flags[0] = 0

    def solve(self, q) -> StrutFKResult:
        """The pose of ``q``; on a failure the last good pose is the next start."""
        if type(q) is not np.ndarray or q.dtype is not _FLOAT64:
            q = np.asarray(q, dtype=float)
        if q.shape != self._shape:
            raise ValueError(f"strut lengths: expected {self.machine.n_legs} values, got shape {q.shape}")
        p, rotation = np.empty(3), np.empty((3, 3))
        code, iterations, misfit = _warm_solve(self.machine.bars, q, self._state, self._flags, self.tol_m,
                                               self.max_iterations, self.divergence_limit_m, p, rotation)
        return StrutFKResult(_CODES[code], p, rotation, iterations, misfit)

    def solve_stream(self, lengths) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`solve` over readings (N, n) in one compiled loop, bit for bit N calls
        of it: (poses (N, 12) as p and R row-major, codes (N,), iterations (N,),
        misfits (N,) in m)."""
        lengths = np.ascontiguousarray(lengths, dtype=float).reshape(-1, self.machine.n_legs)
        n = lengths.shape[0]
        poses, codes = np.empty((n, 12)), np.empty(n, dtype=np.int64)
        iterations, misfits = np.empty(n, dtype=np.int64), np.empty(n)
        B.forward_kinematics_stream_kernel(self.machine.bars, lengths, self._state, self._flags, self.tol_m,
                                           self.max_iterations, self.divergence_limit_m, poses, codes, iterations,
                                           misfits)
        return poses, codes, iterations, misfits


__all__ = ["FKCode", "StrutFK", "StrutFKResult", "StrutMachine", "rate_matrix"]



@kernel()
def pose_jacobians_into(bars, poses, rows, rates) -> int:
    """At each pose of ``poses`` (N, 6): the unit pose Jacobian J_m (MoM3 eq. 2,
    ``bars.unit_pose_jacobian_into``) into ``rows`` (N, n, 6) and the rate matrix
    E(b, c) (rotations.rate_matrix) into ``rates`` (N, 3, 3): the task Jacobian is
    [J_m[:, :3], J_m[:, 3:] E] (``StrutMachine.task_jacobian_batch`` multiplies as
    ``task_jacobian`` does, bit for bit). Returns the index of the first pose where a
    strut has zero length, -1 if none."""
    q = np.zeros(bars.shape[0])
    for i in range(poses.shape[0]):
        r = rpy_rotation_kernel(poses[i, 3], poses[i, 4], poses[i, 5])
        if not B.unit_pose_jacobian_into(bars, poses[i, 0], poses[i, 1], poses[i, 2], r, q, rows[i]):
            return i
        e = rate_matrix_kernel(poses[i, 4], poses[i, 5])
        for k in range(9):
            rates[i, k // 3, k % 3] = e[k]
    return -1
