"""The rail machines: one bar per actuator, its base joint on a rail (ARCHI, Sliding
Star, the Orthoglide, the Delta; ../shared/MACHINE_MODEL.md).

``RailMachine`` is one class for all of them, configured by data:

* the bars (``bars.bar_rows``: rail origin a_i, unit direction u_i, platform joint
  b_i, link length L_i, assembly branch sigma_i), from its ``legs``;
* its ``task_space`` (``RAIL_TASKS``: a planar machine moves in x, y, theta, its
  twist in vx, vy, wz and its rails drawn in the plane; a translating one in
  x, y, z);
* its forward kinematics, by name from ``FORWARD_SOLVERS`` ("least_squares": the
  leg pairs' closed form and Gauss-Newton over all legs, ``planar.py``;
  "three_spheres": ``translational.py``).

Through the kernels of ``bars``, for any such machine: the inverse kinematics (per
pose and batched), J_m, its derivative, the velocity terms of the dynamic model, the
batches, the conditioning, the sub-machines, the velocity transmission factors and
the parallel-singularity measure.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np

from . import bars as B
from .distribution import gram_condition
from .errors import FieldError, JointLimitError, KinematicsError, SingularityError, UnreachablePoseError
from .measures import condition_numbers, cube_grid
from .planar import PlanarLeastSquaresFK
from .task_space import PLANAR, POSITION, TaskSpace
from .translational import ThreeSpheresFK, unit_rows_determinant
from .validation import finite_array, finite_floats


@dataclass(frozen=True)
class RailLeg:
    """One leg of a rail machine (SI units): a carriage on the rail through
    ``rail_origin`` along ``rail_direction`` and a link of ``link_length`` to the
    platform joint ``platform_point`` (platform frame) on its ``assembly`` branch
    (+1 or -1). Points have 2 coordinates on a planar machine, 3 otherwise."""

    name: str
    rail_origin: tuple
    rail_direction: tuple
    link_length: float
    platform_point: tuple
    assembly: int
    joint_limits: tuple[float, float] = (-math.inf, math.inf)


def _describe_planar(x) -> str:
    return f"pose (x={x[0]:.6g} m, y={x[1]:.6g} m, theta={math.degrees(x[2]):.6g} deg)"


def _describe_position(x) -> str:
    return f"position ({x[0]:.6g}, {x[1]:.6g}, {x[2]:.6g}) m"


def _planar_grid(workspace: dict, points_per_axis: int, theta_points: int) -> np.ndarray:
    axes = [np.linspace(*workspace["x"], points_per_axis), np.linspace(*workspace["y"], points_per_axis),
            np.radians(np.linspace(*workspace["theta_deg"], theta_points))]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _cube_grid(workspace: dict, points_per_axis: int, theta_points: int) -> np.ndarray:
    return cube_grid(workspace["center"], workspace["size"], points_per_axis)


class RailTask(NamedTuple):
    """What a task space means for a rail machine."""

    columns: np.ndarray     # the twist components the platform moves in (vx vy vz wx wy wz = 0..5)
    dimension: int          # of its rails and points: 2 for a planar machine (z = 0), 3
    pose_label: str         # what messages call x and x'
    rate_label: str
    describe: Callable      # a pose in words
    grid: Callable          # (workspace, points_per_axis, theta_points) -> poses over the workspace


PLANAR_COLUMNS = np.array([0, 1, 5], dtype=np.int64)
TRANSLATION_COLUMNS = np.array([0, 1, 2], dtype=np.int64)
RAIL_TASKS = {
    PLANAR: RailTask(PLANAR_COLUMNS, 2, "pose", "twist", _describe_planar, _planar_grid),
    POSITION: RailTask(TRANSLATION_COLUMNS, 3, "position", "velocity", _describe_position, _cube_grid),
}
FORWARD_SOLVERS = {"least_squares": PlanarLeastSquaresFK, "three_spheres": ThreeSpheresFK}


def velocity_terms_error(code: int, leg_name: str, label: str, values) -> KinematicsError:
    """The exception for a failure ``code`` of the velocity-terms kernel: ``label``
    and ``values`` name the pose that failed."""
    if code == B.VT_UNREACHABLE:
        return UnreachablePoseError(f"{label} {[float(v) for v in values]} is unreachable for leg {leg_name}")
    return SingularityError(f"leg {leg_name} is perpendicular to its rail (serial singularity)")


@dataclass
class RailMachine:
    """A rail machine (module doc): ``legs`` (``RailLeg``), its ``home`` in task
    coordinates, its ``task_space`` (a key of ``RAIL_TASKS``) and its ``forward``
    kinematics (a key of ``FORWARD_SOLVERS``); ``transmission_bounds`` and
    ``parallel_margin`` (|det| of the unit leg directions below which a pose is
    refused; 0: none) are what the trajectory planner checks (Orthoglide §3.3, §4.3)."""

    name: str
    legs: list
    home: np.ndarray
    task_space: TaskSpace
    forward: str = "least_squares"
    workspace: dict = field(default_factory=dict)
    description: str = ""
    transmission_bounds: tuple[float, float] | None = None
    parallel_margin: float = 0.0

    def __post_init__(self):
        task = RAIL_TASKS.get(self.task_space)
        if task is None:
            raise FieldError("task_space", f"a rail machine moves in one of {[s.name for s in RAIL_TASKS]}, got "
                                           f"{getattr(self.task_space, 'name', self.task_space)!r}")
        if self.forward not in FORWARD_SOLVERS:
            raise FieldError("forward", f"one of {sorted(FORWARD_SOLVERS)}, got {self.forward!r}")
        if len(self.legs) < 3:
            raise FieldError("legs", f"a rail machine needs at least 3 legs, got {len(self.legs)}")
        self.home = finite_array(self.home, "home", (3,))
        self.task_dof = self.spatiality = task.columns.size
        self.twist_columns, self.dimension = task.columns, task.dimension
        self.pose_label, self.rate_label = task.pose_label, task.rate_label
        self._task = task
        legs = self.legs
        self._init_rails([leg.rail_origin for leg in legs], [leg.rail_direction for leg in legs],
                         [leg.link_length for leg in legs], [leg.platform_point for leg in legs],
                         [float(leg.assembly) for leg in legs], [leg.joint_limits for leg in legs],
                         [leg.name for leg in legs])
        self.leg_pairs = self._find_pairs()
        self.fk = FORWARD_SOLVERS[self.forward](self)
        # The per-cycle path calls the solver's own method (no delegation in between).
        self.forward_kinematics_floats = self.fk.floats

    def _init_rails(self, origins, directions, lengths, platform_points, assemblies, limits, names):
        """The bars from per-leg arrays ((n, dimension) points and directions, the
        latter normalised here)."""
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

    def _find_pairs(self) -> list[tuple[int, int]]:
        """Legs sharing a platform point (ARCHI's B12 and B34), when all legs pair up
        into >= 2 points; [] otherwise."""
        groups: dict[tuple, list[int]] = {}
        for i, b in enumerate(self.bars[:, B.COL_B:B.COL_B + 3]):
            groups.setdefault(tuple(round(float(v), 12) for v in b), []).append(i)
        pairs = [tuple(g[:2]) for g in groups.values() if len(g) >= 2]
        return pairs if len(pairs) >= 2 else []

    def with_legs(self, name: str, legs):
        """The same machine with other legs (the plant's true machine: link length
        errors, rail offsets), everything else as it is here."""
        return dataclasses.replace(self, name=name, legs=list(legs))

    # ------------------------------------------------------------------ forward
    def forward_kinematics(self, q, guess=None, **options):
        """The pose of drive positions ``q`` as a ``ForwardKinematicsResult`` (pose
        NaN and the reason when it fails), by the configured solver (``fk``;
        ``options``: its tolerances)."""
        return self.fk.solve(q, guess, **options)

    def forward_kinematics_batch(self, q, guesses=None, **options) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`forward_kinematics` of q (N, n): (poses (N, 3), converged mask);
        failed rows NaN."""
        return self.fk.batch(q, guesses, **options)

    def workspace_grid(self, points_per_axis: int = 11, theta_points: int = 13) -> np.ndarray:
        """A regular grid over the configured workspace: (N, 3) poses (x, y, theta
        over x, y, theta_deg) or positions (over the cube of ``center`` and ``size``)."""
        return self._task.grid(self.workspace, points_per_axis, theta_points)

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
        return self._task.describe(x)

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

    def rows_condition(self, jac) -> float:
        """2-norm condition number of given rows of J_m (n' x 3: a sub-machine's, the
        drives still active), closed form (distribution.gram_condition); inf when
        singular."""
        return gram_condition(jac)

    def condition_number_batch(self, xs) -> np.ndarray:
        """Condition numbers of J_m at poses (N, 3): NaN where unreachable."""
        return condition_numbers(self.jacobian_batch(xs))


    # ------------------------------------------------------------- analyses
    def sub_machines(self) -> list[tuple[int, ...]]:
        """Every non-redundant sub-machine: each choice of task_dof legs (J_124,
        J_134, J_123, J_234 for ARCHI)."""
        return list(itertools.combinations(range(self.n_legs), self.task_dof))

    def sub_machine_name(self, legs: tuple[int, ...]) -> str:
        return "J_" + "".join(str(i + 1) for i in legs)

    def sub_machine_condition_numbers(self, pose) -> dict[tuple[int, ...], float]:
        jac = self.jacobian(pose)
        return {legs: float(np.linalg.cond(jac[list(legs)])) for legs in self.sub_machines()}

    def _bar_vectors(self, x, q=None) -> np.ndarray:
        """e_i = B_i - A_i (n, 3) at the pose x (``bars.bar_vectors_kernel``)."""
        x = finite_floats(x, 3, self.pose_label)
        q = self.inverse_kinematics(x, check_limits=False) if q is None else np.array(finite_floats(q, self.n_legs, "q"))
        p, rot = self._pose_3d(x)
        return B.bar_vectors_kernel(self.bars, float(p[0]), float(p[1]), float(p[2]),
                                    tuple(float(v) for v in rot.ravel()), q)

    def parallel_jacobian(self, x, q=None) -> np.ndarray:
        """A of A x' = B q' (Orthoglide eq. 4; ARCHI §3.2's J_v G): rows
        [e_i, (R b_i) x e_i] on the task's twist columns (the leg vectors of a
        translating machine)."""
        e = self._bar_vectors(x, q)
        if self.twist_columns.max() < 3:
            return e
        _, rot = self._pose_3d(finite_floats(x, 3, self.pose_label))
        rb = self.bars[:, B.COL_B:B.COL_B + 3] @ rot.T
        return np.hstack([e, np.cross(rb, e)])[:, self.twist_columns]

    def serial_jacobian(self, x, q=None) -> np.ndarray:
        """B = diag(e_i . u_i) (Orthoglide eq. 4): J_m = B^-1 A."""
        return np.diag(np.einsum("ij,ij->i", self._bar_vectors(x, q), self.bars[:, B.COL_U:B.COL_U + 3]))

    def parallel_singularity_measure(self, x, q=None) -> float:
        """|det| of the rows of A normalised (Orthoglide §3.3, eq. 4a): 1 when the legs
        are orthogonal (the Orthoglide's isotropic configuration), 0 at a parallel
        singularity (det A = 0: the platform moves with the drives locked and resists
        no force). For a machine of as many legs as task coordinates."""
        self._square("the parallel-singularity measure")
        return float(unit_rows_determinant(self.parallel_jacobian(x, q)))

    def parallel_singularity_measure_batch(self, xs) -> np.ndarray:
        """:meth:`parallel_singularity_measure` for poses (N, 3); NaN where unreachable
        (the rows of J_m are A's rows over e_i . u_i: the same unit rows up to sign;
        NaN at a serial singularity too)."""
        self._square("the parallel-singularity measure")
        with np.errstate(invalid="ignore"):
            return unit_rows_determinant(self.jacobian_batch(xs))

    def _square(self, what: str) -> None:
        if self.n_legs != self.task_dof:
            raise ValueError(f"machine {self.name!r}: {what} needs as many legs as task coordinates "
                             f"({self.task_dof}), it has {self.n_legs} (see sub_machines)")

    def check_parallel_singularity(self, x, margin: float | None = None) -> None:
        """Raise SingularityError when the pose is at a parallel singularity, or within
        ``margin`` (default ``parallel_margin``) of one by :meth:`parallel_singularity_measure`."""
        margin = self.parallel_margin if margin is None else margin
        value = self.parallel_singularity_measure(x)
        if not value > max(margin, 1e-9):
            raise SingularityError(
                f"{self.describe_pose(np.asarray(x, dtype=float))} is {'at' if value <= 1e-9 else 'near'} a parallel "
                f"singularity (Orthoglide §3.3: the legs nearly coplanar, the platform free with the drives locked): "
                f"|det| of the unit leg directions {value:.3g}, parallel_margin {margin:g}")

    def transmission_factors(self, x) -> np.ndarray:
        """Velocity transmission factors psi (Orthoglide §4.3): 1 / the singular values
        of J_m, sorted ascending."""
        sv = np.linalg.svd(self.jacobian(x), compute_uv=False)
        return np.sort(1.0 / sv)

    def transmission_factors_batch(self, xs) -> np.ndarray:
        """psi for poses (N, 3): (N, 3) ascending, NaN where unreachable."""
        jac = self.jacobian_batch(xs)
        out = np.full((jac.shape[0], 3), np.nan)
        ok = np.isfinite(jac).all(axis=(1, 2))
        if ok.any():
            out[ok] = np.sort(1.0 / np.linalg.svd(jac[ok], compute_uv=False), axis=1)
        return out

    def is_isotropic(self, x, tol: float = 1e-9) -> bool:
        """True when J_m J_m^T is a multiple of I, i.e. the condition number is 1
        (Orthoglide §4.1-4.2, eq. 9a-d). The Orthoglide's design also asks the factors
        to equal 1 there (eq. 10): see :meth:`transmission_factors`."""
        return abs(self.condition_number(x) - 1.0) < tol


__all__ = ["FORWARD_SOLVERS", "PLANAR_COLUMNS", "RAIL_TASKS", "RailLeg", "RailMachine", "TRANSLATION_COLUMNS",
           "velocity_terms_error"]
