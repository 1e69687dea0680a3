"""What every rail machine shares: one bar per actuator, its base joint on a rail
(ARCHI, Sliding Star, the Orthoglide, the Delta; ../shared/MACHINE_MODEL.md).

``RailMachine`` holds the model as bars (``bars.bar_rows``: rail origin a_i, unit
direction u_i, platform joint b_i, link length L_i, assembly branch sigma_i) and the
twist components its platform moves in (``twist_columns``: vx vy vz for a
translating platform, vx vy wz for a planar one), and gives, through the kernels of
``bars`` and for any such machine, the inverse kinematics (per pose and batched), J_m,
its derivative, the velocity terms of the dynamic model, the batched J_m and the
conditioning. ``planar.PlanarMachine`` and ``translational.TranslationalMachine``
keep only what differs: their forward kinematics (ARCHI's leg pairs and least
squares; the Orthoglide's three spheres) and their papers' analyses.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import bars as B
from .errors import JointLimitError, KinematicsError, SingularityError, UnreachablePoseError
from .measures import condition_numbers
from .validation import finite_array, finite_floats


def velocity_terms_error(code: int, leg_name: str, label: str, values) -> KinematicsError:
    """The exception for a failure ``code`` of the velocity-terms kernel: ``label``
    and ``values`` name the pose that failed."""
    if code == B.VT_UNREACHABLE:
        return UnreachablePoseError(f"{label} {[float(v) for v in values]} is unreachable for leg {leg_name}")
    return SingularityError(f"leg {leg_name} is perpendicular to its rail (serial singularity)")


class RailMachine:
    """The shared part of a rail machine (module doc). A subclass sets ``pose_label``
    ("pose", "position"), ``rate_label`` ("twist", "velocity") and ``dimension`` (2 for a planar machine: its rails, drawn
    in the plane; 3) and calls :meth:`_init_rails` from its constructor."""

    pose_label = "pose"
    rate_label = "twist"          # what messages call x'
    dimension = 3

    def _init_rails(self, origins, directions, lengths, platform_points, assemblies, limits, names, columns):
        """The bars from per-leg arrays ((n, dimension) points and directions, the
        latter normalised here) and the task's twist ``columns``."""
        n = len(names)
        flat = np.zeros((n, 3 - self.dimension))             # a planar machine in z = 0
        origins, platform_points = (np.hstack([np.asarray(v, dtype=float), flat]) for v in (origins, platform_points))
        u = np.hstack([np.asarray(directions, dtype=float), flat])
        u = u / np.linalg.norm(u, axis=1, keepdims=True)
        self.n_legs, self.leg_names = n, list(names)
        limits = np.asarray(limits, dtype=float).reshape(n, 2)
        self.joint_lower, self.joint_upper = limits[:, 0].copy(), limits[:, 1].copy()
        self._limits_f = (self.joint_lower.tolist(), self.joint_upper.tolist())   # floats: the per-cycle check
        self.bars = B.bar_rows(origins, platform_points, actuator=np.arange(n), kind=B.RAIL, rail=u,
                               length=np.asarray(lengths, dtype=float), branch=np.asarray(assemblies, dtype=float))
        self.twist_columns = np.asarray(columns, dtype=np.int64)

    def with_legs(self, name: str, legs):
        """The same machine with other legs (the plant's true machine: link length
        errors, rail offsets), everything else as it is here."""
        return dataclasses.replace(self, name=name, legs=list(legs))

    # ------------------------------------------------- the bars (machine.ParallelMachine)
    @property
    def rail_origins(self) -> np.ndarray:
        """a_i, the origin of each drive's rail (n, dimension), world frame."""
        return self.bars[:, B.COL_A:B.COL_A + self.dimension].copy()

    @property
    def rail_directions(self) -> np.ndarray:
        """u_i, each rail's unit direction (n, dimension): a carriage is at a_i + q_i u_i."""
        return self.bars[:, B.COL_U:B.COL_U + self.dimension].copy()

    def _pose_3d(self, x) -> tuple[np.ndarray, np.ndarray]:
        """(p (3,), R (3, 3)) of task coordinates x (``bars.task_pose_twist``)."""
        px, py, pz, r, _ = B.task_pose_twist.py_func(self.twist_columns, x[0], x[1], x[2], 0.0, 0.0, 0.0)
        return np.array([px, py, pz]), np.array(r).reshape(3, 3)

    def _poses_3d(self, xs) -> tuple[np.ndarray, np.ndarray]:
        """Task coordinates (N, 3) as the bar kernels take them: positions (N, 3) and
        rotations (N, 9) row-major."""
        xs = np.asarray(xs, dtype=float).reshape(-1, 3)
        positions, rotations = np.zeros((len(xs), 3)), np.tile(np.eye(3).reshape(9), (len(xs), 1))
        for i, c in enumerate(self.twist_columns.tolist()):
            if c < 3:
                positions[:, c] = xs[:, i]
            else:            # a turn about base axis c - 3 (a planar machine's about z)
                co, si = np.cos(xs[:, i]), np.sin(xs[:, i])
                a, b = [k for k in range(3) if k != c - 3]
                rotations[:, 3 * a + a], rotations[:, 3 * a + b] = co, -si
                rotations[:, 3 * b + a], rotations[:, 3 * b + b] = si, co
        return positions, rotations

    def leg_joints(self, x, q=None) -> tuple[np.ndarray, np.ndarray]:
        """Each leg's two joints at the pose x in world coordinates, (n, 3) each: the
        carriage A_i = a_i + q_i u_i and the platform joint B_i = p + R b_i (z = 0 on
        a planar machine). ``q``: the drive positions (default: the inverse kinematics)."""
        q = self.inverse_kinematics(x, check_limits=False) if q is None else np.asarray(q, dtype=float)
        p, rot = self._pose_3d(x)
        bars = self.bars
        return (bars[:, B.COL_A:B.COL_A + 3] + q[:, None] * bars[:, B.COL_U:B.COL_U + 3],
                p + bars[:, B.COL_B:B.COL_B + 3] @ rot.T)

    # ----------------------------------------------------------------- inverse
    def inverse_kinematics(self, x, check_limits: bool = True) -> np.ndarray:
        """Drive positions q (m) of the pose x, each in closed form on its assembly
        branch (``bars.actuators_into``; ARCHI §3.1, Orthoglide §3.1). Raises
        UnreachablePoseError naming the leg whose link cannot reach its platform
        joint, and JointLimitError when ``check_limits`` and a drive leaves its range."""
        x0, x1, x2 = finite_floats(x, 3, self.pose_label)
        q, code, leg = B.rail_task_inverse_kinematics_kernel(self.bars, self.n_legs, self.twist_columns, x0, x1, x2)
        if code != B.IK_OK:     # also NaN from overflowing inputs
            p, rot = self._pose_3d((x0, x1, x2))
            w = p + rot @ self.bars[leg, B.COL_B:B.COL_B + 3] - self.bars[leg, B.COL_A:B.COL_A + 3]
            u = self.bars[leg, B.COL_U:B.COL_U + 3]
            with np.errstate(all="ignore"):
                away = float(np.sqrt(max(float(w @ w - (w @ u) ** 2), 0.0)))
            raise UnreachablePoseError(
                f"{self.describe_pose((x0, x1, x2))} is unreachable: leg {self.leg_names[leg]} platform point is "
                f"{away:.6g} m from its rail, link_length is {self.bars[leg, B.COL_LENGTH]:.6g} m")
        if check_limits:
            for i, (qi, lo, hi) in enumerate(zip(q.tolist(), self._limits_f[0], self._limits_f[1])):
                if not lo <= qi <= hi:
                    raise JointLimitError(f"leg {self.leg_names[i]}: position {qi:.6g} m outside joint_limits "
                                          f"[{lo:.6g}, {hi:.6g}] m")
        return q

    def describe_pose(self, x) -> str:
        """The pose x in words, for messages."""
        return f"{self.pose_label} ({', '.join(f'{v:.6g}' for v in x)})"

    def check_joint_limits(self, q) -> None:
        """Raise JointLimitError naming the first drive outside its joint_limits."""
        bad = (q < self.joint_lower) | (q > self.joint_upper)
        if bad.any():
            i = int(np.argmax(bad))
            raise JointLimitError(
                f"leg {self.leg_names[i]}: position {q[i]:.6g} m outside joint_limits "
                f"[{self.joint_lower[i]:.6g}, {self.joint_upper[i]:.6g}] m")

    def inverse_kinematics_batch(self, xs) -> tuple[np.ndarray, np.ndarray]:
        """IK of poses (N, 3): (q (N, n), NaN for a leg that cannot reach; the
        reachable mask (N,)). Joint limits: ``within_joint_limits``."""
        positions, rotations = self._poses_3d(finite_array(xs, f"{self.pose_label}s", (-1, 3)))
        q = np.empty((positions.shape[0], self.n_legs))
        reachable = np.empty(positions.shape[0], dtype=bool)
        B.inverse_kinematics_batch_kernel(self.bars, positions, rotations, q, reachable)
        return q, reachable

    def within_joint_limits(self, q) -> np.ndarray:
        """Mask of rows of q (N, n) whose drives are all inside their limits."""
        q = np.asarray(q, dtype=float)
        return np.all((q >= self.joint_lower) & (q <= self.joint_upper), axis=-1)

    # ---------------------------------------------------------------- jacobians
    def jacobian(self, x, q=None) -> np.ndarray:
        """J_m (n x 3), q' = J_m x' (ARCHI §3.2, Orthoglide eq. 8): rows
        [e_i, (R b_i) x e_i] / (e_i . u_i) on the task's twist columns. Raises
        SingularityError at a serial singularity (a link perpendicular to its rail).
        (``q``: unused, the kernel closes the legs itself.)"""
        return self.velocity_terms_arrays(finite_floats(x, 3, self.pose_label), (0.0, 0.0, 0.0))[1]

    def jacobian_derivative(self, x, xdot, q=None) -> np.ndarray:
        """dJ_m/dt along x' (ARCHI §3.4 uses it in q'' = J_m x'' + J_m' x'):
        ``bars.rail_row_terms``' rates, g'/s - g s'/s^2."""
        x, v = finite_floats(x, 3, self.pose_label), finite_floats(xdot, 3, self.rate_label)
        rates, code, leg = B.rail_task_jacobian_derivative_kernel(self.bars, self.n_legs, self.twist_columns, *x, *v)
        if code != B.VT_OK:
            self.raise_velocity_terms_error(code, leg, x)
        return rates

    def velocity_terms(self, x, xdot) -> tuple[list, list, list, list]:
        """(q, rows of J_m, q' = J_m x', J_m' x') as lists of floats for the dynamic
        model; see :meth:`velocity_terms_arrays`."""
        q, rows, qdot, bias = self.velocity_terms_arrays(x, xdot)
        return q.tolist(), rows.tolist(), qdot.tolist(), bias.tolist()

    def velocity_terms_arrays(self, x, xdot) -> tuple:
        """(q (n,), J_m (n, 3), q', J_m' x') at the pose x moving at x', the
        velocity-product part of q'' = J_m x'' + J_m' x' included (ARCHI §3.2, §3.4;
        ``bars.rail_task_velocity_terms_kernel``, compiled). Raises
        UnreachablePoseError / SingularityError naming the leg."""
        if len(x) != 3 or len(xdot) != 3:
            raise ValueError(f"velocity terms: {self.pose_label} and its rate need 3 values each, got {len(x)} and "
                             f"{len(xdot)}")
        q, rows, qdot, bias, code, leg = B.rail_task_velocity_terms_kernel(
            self.bars, self.n_legs, self.twist_columns, x[0], x[1], x[2], xdot[0], xdot[1], xdot[2])
        if code != B.VT_OK:
            self.raise_velocity_terms_error(code, leg, x)
        return q, rows, qdot, bias

    def raise_velocity_terms_error(self, code: int, leg: int, x) -> None:
        """Raise the exception for a failure ``code`` of the velocity-terms kernel."""
        raise velocity_terms_error(code, self.leg_names[leg], self.pose_label, x)

    def jacobian_batch(self, xs) -> np.ndarray:
        """J_m at poses (N, 3): (N, n, 3), NaN rows where unreachable, inf at a serial
        singularity (``bars.rail_jacobian_batch_kernel``: the per-pose kernel on
        every row)."""
        positions, rotations = self._poses_3d(xs)
        n = positions.shape[0]
        q, rows, ok = np.empty((n, self.n_legs)), np.empty((n, self.n_legs, 3)), np.empty(n, dtype=bool)
        B.rail_jacobian_batch_kernel(self.bars, positions, rotations, self.twist_columns, q, rows, ok)
        return rows

    def task_jacobian_batch(self, xs) -> np.ndarray:
        """q' = J x' for the task coordinates' rates: the twist's here (J_m)."""
        return self.jacobian_batch(xs)

    def condition_number(self, x) -> float:
        """2-norm condition number of J_m (ARCHI §3.3, Fig. 10)."""
        return float(np.linalg.cond(self.jacobian(x)))

    def condition_number_batch(self, xs) -> np.ndarray:
        """Condition numbers of J_m at poses (N, 3): NaN where unreachable."""
        return condition_numbers(self.jacobian_batch(xs))


__all__ = ["RailMachine", "velocity_terms_error"]
