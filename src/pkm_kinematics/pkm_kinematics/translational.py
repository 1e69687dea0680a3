"""Three-axis translational PKMs: three prismatic actuators, parallelogram legs.

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
twist columns vx, vy, vz): a ``rails.RailMachine``, whose IK, J_m, velocity terms
and batches are every rail machine's; the forward kinematics
(``bars.three_rail_forward_kinematics_kernel``) and the Orthoglide's analyses are
this class's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import bars as B
from .errors import SingularityError, UnreachablePoseError
from .measures import cube_grid
from .rails import RailMachine
from .task_space import POSITION
from .validation import finite_array, finite_floats

IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
TRANSLATION_COLUMNS = np.array([0, 1, 2], dtype=np.int64)    # the task's twist components: vx, vy, vz


@dataclass(frozen=True)
class TranslationalLeg:
    name: str
    rail_origin: tuple[float, float, float]
    rail_direction: tuple[float, float, float]
    link_length: float
    platform_offset: tuple[float, float, float]
    assembly: int
    joint_limits: tuple[float, float] = (-math.inf, math.inf)


@dataclass
class TranslationalMachine(RailMachine):
    """A 3-DOF translational PKM with three P-Pa legs (see module docstring): a
    ``RailMachine`` translating, with its closed-form forward kinematics and the
    Orthoglide's analyses."""

    name: str
    legs: list[TranslationalLeg]
    home_position: np.ndarray
    workspace: dict = field(default_factory=dict)
    transmission_bounds: tuple[float, float] | None = None
    description: str = ""
    parallel_margin: float = 0.0     # poses with parallel_singularity_measure below it are refused (0: none)

    pose_label = "position"
    rate_label = "velocity"
    dimension = 3

    def __post_init__(self):
        if len(self.legs) != 3:
            raise ValueError(f"legs: a translational machine has exactly 3 legs, got {len(self.legs)}")
        self.home_position = finite_array(self.home_position, "home_position", (3,))
        self.task_dof = self.spatiality = 3     # three translations
        self.task_space = POSITION
        legs = self.legs
        self._init_rails([leg.rail_origin for leg in legs], [leg.rail_direction for leg in legs],
                         [leg.link_length for leg in legs], [leg.platform_offset for leg in legs],
                         [float(leg.assembly) for leg in legs], [leg.joint_limits for leg in legs],
                         [leg.name for leg in legs], TRANSLATION_COLUMNS)
        self._o, self._e = self.rail_origins, self.rail_directions
        self._c = self.bars[:, B.COL_B:B.COL_B + 3].copy()
        self._sigma = self.bars[:, B.COL_BRANCH].copy()
        # Forward branch: the platform lies on one side of the plane through the three
        # sphere centres; that side only changes through a parallel singularity
        # (Orthoglide §3.3), so it is the working mode.
        rho = self.inverse_kinematics(self.home_position, check_limits=False)
        centres = self._o + rho[:, None] * self._e - self._c
        normal = np.cross(centres[1] - centres[0], centres[2] - centres[0])
        self._fk_side = math.copysign(1.0, float(normal @ (self.home_position - centres[0])))

    @property
    def home(self) -> np.ndarray:
        """The home position (x, y, z)."""
        return self.home_position

    def describe_pose(self, x) -> str:
        return f"position ({x[0]:.6g}, {x[1]:.6g}, {x[2]:.6g}) m"

    # ----------------------------------------------------------------- forward
    def forward_kinematics(self, rho) -> np.ndarray:
        """Tool-centre position from actuator positions: the intersection of three
        spheres (centres B_i - c_i, radii L_i) on the working-mode side. Closed form.

        Raises UnreachablePoseError when the spheres do not meet or when the point
        found needs a leg on its other assembly branch, SingularityError when the centres
        are collinear.
        """
        r = finite_floats(rho, 3, "rho")
        return np.array(self.forward_kinematics_floats(r))

    def forward_kinematics_floats(self, rho, guess=None) -> tuple[float, float, float]:
        """:meth:`forward_kinematics` on the per-cycle path: ``rho`` 3 floats (finiteness
        unchecked: the caller checked it), the position as a tuple. ``guess`` is
        ignored (the closed form needs none; the planar machines' signature).
        Compiled (``bars.three_rail_forward_kinematics_kernel``)."""
        if len(rho) != 3:
            raise ValueError(f"rho: expected 3 actuator positions, got {len(rho)}")
        px, py, pz, code, leg = B.three_rail_forward_kinematics_kernel(self.bars, float(rho[0]), float(rho[1]),
                                                                       float(rho[2]), self._fk_side)
        if code == B.TRI_OK:
            return px, py, pz
        r = [float(v) for v in rho]
        if code == B.TRI_COLLINEAR:
            raise SingularityError(f"actuator positions {r} m: the three sphere centres are collinear "
                                   "(the platform position is not determined)")
        if code == B.TRI_NOT_MEETING:
            raise UnreachablePoseError(f"actuator positions {r} m cannot be assembled: the legs do not meet")
        raise UnreachablePoseError(f"actuator positions {r} m assemble only with leg {self.leg_names[leg]} on its "
                                   f"other branch (assembly {int(self._sigma[leg]):+d})")

    def forward_kinematics_batch(self, rho) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics of rho (N, 3), the per-pose kernel on every row: (positions,
        ok mask); NaN rows where the legs do not meet or a leg would be on its other branch."""
        rho = np.ascontiguousarray(finite_array(rho, "rho", (-1, 3)))
        p, ok = np.empty(rho.shape), np.empty(rho.shape[0], dtype=bool)
        B.three_rail_forward_kinematics_batch_kernel(self.bars, rho, self._fk_side, p, ok)
        return p, ok

    # ---------------------------------------------------------------- jacobians
    def parallel_jacobian(self, position, rho=None) -> np.ndarray:
        """A = [(c_i - b_i)^T]: rows are the leg vectors (Orthoglide eq. 4;
        ``bars.bar_vectors_kernel``)."""
        px, py, pz = finite_floats(position, 3, "position")
        rho = (self.inverse_kinematics((px, py, pz), check_limits=False) if rho is None
               else np.array(finite_floats(rho, 3, "rho")))
        return B.bar_vectors_kernel(self.bars, px, py, pz, IDENTITY, rho)

    def parallel_singularity_measure(self, position, rho=None) -> float:
        """|det| of the unit leg directions, the rows of A normalised (Orthoglide §3.3,
        eq. 4a): 1 when the legs are orthogonal (the Orthoglide's isotropic
        configuration), 0 at a parallel singularity (det A = 0: the legs coplanar or
        parallel, where the platform moves with the drives locked and resists no
        force)."""
        return float(unit_rows_determinant(self.parallel_jacobian(position, rho)))

    def parallel_singularity_measure_batch(self, positions) -> np.ndarray:
        """:meth:`parallel_singularity_measure` for positions (N, 3); NaN where unreachable
        (the rows of J_m are the leg vectors over e_i . u_i: the same unit rows up to
        sign; NaN at a serial singularity too)."""
        with np.errstate(invalid="ignore"):
            return unit_rows_determinant(self.jacobian_batch(positions))

    def check_parallel_singularity(self, position, margin: float | None = None) -> None:
        """Raise SingularityError when the pose is at a parallel singularity, or within
        ``margin`` (default ``parallel_margin``) of one by :meth:`parallel_singularity_measure`."""
        margin = self.parallel_margin if margin is None else margin
        value = self.parallel_singularity_measure(position)
        if not value > max(margin, 1e-9):
            p = ", ".join(f"{v:.6g}" for v in np.asarray(position, dtype=float))
            raise SingularityError(
                f"position ({p}) m is {'at' if value <= 1e-9 else 'near'} a parallel singularity (Orthoglide "
                f"§3.3: the legs nearly coplanar, the platform free with the drives locked): |det| of the unit leg "
                f"directions {value:.3g}, parallel_margin {margin:g}")

    def serial_jacobian(self, position, rho=None) -> np.ndarray:
        """B = diag((c_i - b_i)^T e_i) (Orthoglide eq. 4)."""
        a = self.parallel_jacobian(position, rho)
        return np.diag(np.einsum("ij,ij->i", a, self._e))

    def workspace_grid(self, points_per_axis: int = 11, theta_points: int = 13) -> np.ndarray:
        """A regular grid over the configured workspace cube: (N, 3) positions
        (``theta_points``: the planar machines' signature, unused)."""
        return cube_grid(self.workspace["center"], self.workspace["size"], points_per_axis)

    def transmission_factors(self, position) -> np.ndarray:
        """Velocity transmission factors psi (Orthoglide §4.3), sorted ascending."""
        sv = np.linalg.svd(self.jacobian(position), compute_uv=False)
        return np.sort(1.0 / sv)

    def transmission_factors_batch(self, positions) -> np.ndarray:
        """psi for positions (N, 3): (N, 3) ascending, NaN where unreachable."""
        jac = self.jacobian_batch(positions)
        out = np.full((jac.shape[0], 3), np.nan)
        ok = np.isfinite(jac).all(axis=(1, 2))
        if ok.any():
            out[ok] = np.sort(1.0 / np.linalg.svd(jac[ok], compute_uv=False), axis=1)
        return out

    def is_isotropic(self, position, tol: float = 1e-9) -> bool:
        """True when J_m J_m^T is a multiple of I, i.e. the condition number is 1
        (Orthoglide §4.1-4.2, eq. 9a-d). The Orthoglide's design also asks the factors
        to equal 1 there (eq. 10): see :meth:`transmission_factors`."""
        return abs(self.condition_number(position) - 1.0) < tol


def unit_rows_determinant(rows) -> np.ndarray:
    """|det| of the rows normalised to unit length (the last two axes): the parallel
    singularity measure of Orthoglide §3.3 for the leg vectors, or for any rows
    parallel to them (J_m's)."""
    rows = np.asarray(rows, dtype=float)
    return np.abs(np.linalg.det(rows / np.linalg.norm(rows, axis=-1, keepdims=True)))
