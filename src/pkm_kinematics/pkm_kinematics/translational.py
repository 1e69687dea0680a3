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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import JointLimitError, SingularityError, UnreachablePoseError
from .jit import kernel
from .measures import condition_numbers, cube_grid
from .planar import VT_OK, VT_SINGULAR, VT_UNREACHABLE, empty_velocity_terms, velocity_terms_error
from .task_space import POSITION
from .validation import finite_array, finite_floats


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (np.cross costs ~30 us per call here)."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


@kernel("(float64[:, :], float64, float64, float64, float64, float64, float64)")
def velocity_terms_kernel(legs, px, py, pz, vx, vy, vz):
    """(rho, J_m (3, 3), rhodot = J_m pdot, Jdot_m pdot, code, leg) at the position p
    and velocity v (Orthoglide eq. 3-8): per leg (rows of ``legs``: o, e, L^2, c,
    sigma) the leg vector a_i = w_i - rho_i e_i, s_i = a_i . e_i, the row a_i / s_i,
    rhodot_i = a_i . v / s_i, adot_i = v - rhodot_i e_i and
    (Jdot v)_i = adot_i . v / s_i - (a_i . v)(adot_i . e_i) / s_i^2.
    ``code`` VT_UNREACHABLE or VT_SINGULAR names ``leg``."""
    n = legs.shape[0]
    rho, rows, rhodots, biases = empty_velocity_terms(n)
    for k in range(n):
        ox, oy, oz, ex, ey, ez, l2 = legs[k, 0], legs[k, 1], legs[k, 2], legs[k, 3], legs[k, 4], legs[k, 5], \
            legs[k, 6]
        cx, cy, cz, sigma = legs[k, 7], legs[k, 8], legs[k, 9], legs[k, 10]
        wx, wy, wz = px + cx - ox, py + cy - oy, pz + cz - oz
        a = wx * ex + wy * ey + wz * ez
        disc = l2 - (wx * wx + wy * wy + wz * wz) + a * a
        if not disc >= 0.0:
            return rho, rows, rhodots, biases, VT_UNREACHABLE, k
        r = a + sigma * math.sqrt(disc)
        ax, ay, az = wx - r * ex, wy - r * ey, wz - r * ez
        sv = ax * ex + ay * ey + az * ez
        if sv * sv <= 1e-18 * l2:
            return rho, rows, rhodots, biases, VT_SINGULAR, k
        av = ax * vx + ay * vy + az * vz
        rd = av / sv
        adx, ady, adz = vx - rd * ex, vy - rd * ey, vz - rd * ez
        rho[k] = r
        rows[k, 0], rows[k, 1], rows[k, 2] = ax / sv, ay / sv, az / sv
        rhodots[k] = rd
        biases[k] = (adx * vx + ady * vy + adz * vz) / sv - av * (adx * ex + ady * ey + adz * ez) / (sv * sv)
    return rho, rows, rhodots, biases, VT_OK, -1


# _forward_kinematics_kernel outcome codes
FK_OK, FK_COLLINEAR, FK_NOT_MEETING, FK_OTHER_BRANCH = range(4)


@kernel("(float64[:, :], float64, float64, float64, float64)")
def _forward_kinematics_kernel(legs, r0, r1, r2, side):
    """(px, py, pz, code, leg): the intersection of the three spheres (centres
    S_i = o_i + rho_i e_i - c_i, radii L_i; rows of ``legs``: o, e, L^2, c, sigma) on
    the working-mode ``side`` of the centres' plane, then the assembly branch of each
    leg checked: (C_i - B_i) . e_i has the sign of -sigma_i. ``leg`` names the leg of
    FK_OTHER_BRANCH."""
    rho = (r0, r1, r2)
    s = np.empty((3, 3))
    for i in range(3):
        for k in range(3):
            s[i, k] = legs[i, k] + rho[i] * legs[i, 3 + k] - legs[i, 7 + k]
    sq1, sq2, sq3 = legs[0, 6], legs[1, 6], legs[2, 6]          # squared radii L_i^2
    ux, uy, uz = s[1, 0] - s[0, 0], s[1, 1] - s[0, 1], s[1, 2] - s[0, 2]
    vx, vy, vz = s[2, 0] - s[0, 0], s[2, 1] - s[0, 1], s[2, 2] - s[0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    n2 = nx * nx + ny * ny + nz * nz
    if not n2 > 1e-18 * (ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz):
        return 0.0, 0.0, 0.0, FK_COLLINEAR, -1
    k2 = 0.5 * (sq1 - sq2 + ux * ux + uy * uy + uz * uz)
    k3 = 0.5 * (sq1 - sq3 + vx * vx + vy * vy + vz * vz)
    # foot of the intersection line: (k2 (v x n) + k3 (n x u)) / |n|^2
    fx = (k2 * (vy * nz - vz * ny) + k3 * (ny * uz - nz * uy)) / n2
    fy = (k2 * (vz * nx - vx * nz) + k3 * (nz * ux - nx * uz)) / n2
    fz = (k2 * (vx * ny - vy * nx) + k3 * (nx * uy - ny * ux)) / n2
    rest = sq1 - (fx * fx + fy * fy + fz * fz)
    if not rest >= 0.0:
        return 0.0, 0.0, 0.0, FK_NOT_MEETING, -1
    h = side * math.sqrt(rest / n2)
    px, py, pz = s[0, 0] + fx + h * nx, s[0, 1] + fy + h * ny, s[0, 2] + fz + h * nz
    for i in range(3):
        ex, ey, ez = legs[i, 3], legs[i, 4], legs[i, 5]
        along = ((px + legs[i, 7] - legs[i, 0] - rho[i] * ex) * ex + (py + legs[i, 8] - legs[i, 1] - rho[i] * ey) * ey
                 + (pz + legs[i, 9] - legs[i, 2] - rho[i] * ez) * ez)
        if along * legs[i, 10] > 0.0:
            return px, py, pz, FK_OTHER_BRANCH, i
    return px, py, pz, FK_OK, -1


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
class TranslationalMachine:
    """A 3-DOF translational PKM with three P-Pa legs (see module docstring)."""

    name: str
    legs: list[TranslationalLeg]
    home_position: np.ndarray
    workspace: dict = field(default_factory=dict)
    transmission_bounds: tuple[float, float] | None = None
    description: str = ""
    parallel_margin: float = 0.0     # poses with parallel_singularity_measure below it are refused (0: none)

    def __post_init__(self):
        if len(self.legs) != 3:
            raise ValueError(f"legs: a translational machine has exactly 3 legs, got {len(self.legs)}")
        self.home_position = finite_array(self.home_position, "home_position", (3,))
        self.n_legs = 3
        self.task_dof = self.spatiality = 3     # three translations
        self.task_space = POSITION
        self.leg_names = [leg.name for leg in self.legs]
        self._o = np.array([leg.rail_origin for leg in self.legs], dtype=float)
        e = np.array([leg.rail_direction for leg in self.legs], dtype=float)
        self._e = e / np.linalg.norm(e, axis=1, keepdims=True)
        self._length = np.array([leg.link_length for leg in self.legs], dtype=float)
        self._length2 = self._length**2
        self._c = np.array([leg.platform_offset for leg in self.legs], dtype=float)
        self._sigma = np.array([float(leg.assembly) for leg in self.legs])
        self.joint_lower = np.array([leg.joint_limits[0] for leg in self.legs], dtype=float)
        self.joint_upper = np.array([leg.joint_limits[1] for leg in self.legs], dtype=float)
        # float tuples for the per-cycle scalar paths (see PlanarMachine)
        self._legs_f = [(*map(float, o), *map(float, e), float(l2), *map(float, c), float(sg), float(lo),
                         float(hi), name)
                        for o, e, l2, c, sg, lo, hi, name in zip(
                            self._o, self._e, self._length2, self._c, self._sigma,
                            self.joint_lower, self.joint_upper, self.leg_names)]
        # (o, e, L^2, c, sigma) per leg for the compiled velocity terms
        self._legs_a = np.array([leg[:11] for leg in self._legs_f], dtype=float)
        # Forward branch: the platform lies on one side of the plane through the three
        # sphere centres; that side only changes through a parallel singularity
        # (Orthoglide §3.3: the points coplanar), so it is the working mode.
        rho = self.inverse_kinematics(self.home_position, check_limits=False)
        centres = self._o + rho[:, None] * self._e - self._c
        normal = np.cross(centres[1] - centres[0], centres[2] - centres[0])
        self._fk_side = math.copysign(1.0, float(normal @ (self.home_position - centres[0])))

    # ------------------------------------------------- the bars (machine.ParallelMachine)
    @property
    def home(self) -> np.ndarray:
        """The home position (x, y, z)."""
        return self.home_position

    @property
    def rail_origins(self) -> np.ndarray:
        """o_i, the origin of each drive's rail (3, 3), world frame."""
        return self._o.copy()

    @property
    def rail_directions(self) -> np.ndarray:
        """e_i, each rail's unit direction (3, 3): a carriage is at o_i + rho_i e_i."""
        return self._e.copy()

    @property
    def leg_kernel_data(self) -> np.ndarray:
        """The per-leg rows the compiled kernels take (o, e, L^2, c, sigma); read only."""
        return self._legs_a

    def leg_joints(self, position, q=None) -> tuple[np.ndarray, np.ndarray]:
        """Each leg's two joints at ``position`` in world coordinates, (3, 3) each: the
        carriage o_i + rho_i e_i and the platform joint p + c_i (Orthoglide §3.1; the
        parallelogram drawn as one bar). ``q``: the drive positions (default: the
        inverse kinematics)."""
        q = self.inverse_kinematics(position, check_limits=False) if q is None else np.asarray(q, dtype=float)
        return self._o + q[:, None] * self._e, np.asarray(position, dtype=float)[None, :] + self._c

    # ----------------------------------------------------------------- inverse
    def inverse_kinematics(self, position, check_limits: bool = True) -> np.ndarray:
        """Actuator positions rho (m) of the tool-centre position p (m). Closed form."""
        px, py, pz = finite_floats(position, 3, "position")
        rho = []
        for ox, oy, oz, ex, ey, ez, l2, cx, cy, cz, sigma, lo, hi, name in self._legs_f:
            wx, wy, wz = px + cx - ox, py + cy - oy, pz + cz - oz
            a = wx * ex + wy * ey + wz * ez
            disc = l2 - (wx * wx + wy * wy + wz * wz) + a * a
            if disc < 0.0:
                raise UnreachablePoseError(
                    f"position ({px:.6g}, {py:.6g}, {pz:.6g}) m is unreachable: leg {name} joint is "
                    f"{math.sqrt(l2 - disc):.6g} m from its rail, link_length is {math.sqrt(l2):.6g} m")
            r = a + sigma * math.sqrt(disc)
            if check_limits and not lo <= r <= hi:
                raise JointLimitError(f"leg {name}: position {r:.6g} m outside joint_limits "
                                      f"[{lo:.6g}, {hi:.6g}] m")
            rho.append(r)
        return np.array(rho)

    def check_joint_limits(self, rho) -> None:
        bad = (rho < self.joint_lower) | (rho > self.joint_upper)
        if bad.any():
            i = int(np.argmax(bad))
            raise JointLimitError(
                f"leg {self.leg_names[i]}: position {rho[i]:.6g} m outside joint_limits "
                f"[{self.joint_lower[i]:.6g}, {self.joint_upper[i]:.6g}] m")

    def inverse_kinematics_batch(self, positions) -> tuple[np.ndarray, np.ndarray]:
        """IK for positions (N, 3): (rho (N, 3) NaN where unreachable, reachable mask)."""
        p = finite_array(positions, "positions", (-1, 3))
        w = p[:, None, :] + self._c - self._o
        a = np.einsum("nij,ij->ni", w, self._e)
        disc = self._length2 - np.einsum("nij,nij->ni", w, w) + a * a
        ok = disc >= 0.0
        rho = a + self._sigma * np.sqrt(np.where(ok, disc, np.nan))
        return rho, ok.all(axis=1)

    def within_joint_limits(self, rho) -> np.ndarray:
        rho = np.asarray(rho, dtype=float)
        return np.all((rho >= self.joint_lower) & (rho <= self.joint_upper), axis=-1)

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
        Compiled (:func:`_forward_kinematics_kernel`)."""
        if len(rho) != 3:
            raise ValueError(f"rho: expected 3 actuator positions, got {len(rho)}")
        px, py, pz, code, leg = _forward_kinematics_kernel(self._legs_a, float(rho[0]), float(rho[1]),
                                                           float(rho[2]), self._fk_side)
        if code == FK_OK:
            return px, py, pz
        r = [float(v) for v in rho]
        if code == FK_COLLINEAR:
            raise SingularityError(f"actuator positions {r} m: the three sphere centres are collinear "
                                   "(the platform position is not determined)")
        if code == FK_NOT_MEETING:
            raise UnreachablePoseError(f"actuator positions {r} m cannot be assembled: the legs do not meet")
        raise UnreachablePoseError(f"actuator positions {r} m assemble only with leg {self.leg_names[leg]} on its "
                                   f"other branch (assembly {int(self._sigma[leg]):+d})")

    def forward_kinematics_batch(self, rho) -> tuple[np.ndarray, np.ndarray]:
        """Vectorized forward kinematics, rho (N, 3): (positions, ok mask); NaN rows where
        the legs do not meet or a leg would be on its other branch."""
        rho = finite_array(rho, "rho", (-1, 3))
        centres = self._o + rho[:, :, None] * self._e - self._c
        with np.errstate(invalid="ignore", divide="ignore"):
            p = self._trilaterate(centres, self._length2)
            legs = p[:, None, :] + self._c - self._o - rho[:, :, None] * self._e
            on_branch = np.all(np.einsum("nij,ij->ni", legs, self._e) * self._sigma < 0.0, axis=1)
        ok = np.isfinite(p).all(axis=1) & on_branch
        p[~ok] = np.nan
        return p, ok

    def _trilaterate(self, centres: np.ndarray, r2: np.ndarray) -> np.ndarray:
        """Intersection of 3 spheres per row, centres (N, 3, 3): the point on the
        configured side of the centres' plane, NaN where the spheres do not meet."""
        s1, s2, s3 = centres[:, 0], centres[:, 1], centres[:, 2]
        d21, d31 = s2 - s1, s3 - s1
        n = _cross(d21, d31)
        n2 = np.einsum("ij,ij->i", n, n)
        # point in the plane equidistant as required: solve for the foot p0 of the
        # intersection line: (p0 - s1).d21 = k2, (p0 - s1).d31 = k3, (p0 - s1).n = 0
        k2 = 0.5 * (r2[0] - r2[1] + np.einsum("ij,ij->i", d21, d21))
        k3 = 0.5 * (r2[0] - r2[2] + np.einsum("ij,ij->i", d31, d31))
        # (p0 - s1) = (k2 (d31 x n) + k3 (n x d21)) / |n|^2
        p0 = s1 + (k2[:, None] * _cross(d31, n) + k3[:, None] * _cross(n, d21)) / n2[:, None]
        rest = r2[0] - np.einsum("ij,ij->i", p0 - s1, p0 - s1)
        with np.errstate(invalid="ignore"):
            h = np.sqrt(np.where(rest >= 0.0, rest, np.nan) / n2)
        return p0 + (self._fk_side * h)[:, None] * n

    # ---------------------------------------------------------------- jacobians
    def parallel_jacobian(self, position, rho=None) -> np.ndarray:
        """A = [(c_i - b_i)^T]: rows are the leg vectors (Orthoglide eq. 4)."""
        p = np.array(finite_floats(position, 3, "position"))
        rho = (self.inverse_kinematics(p, check_limits=False) if rho is None
               else np.array(finite_floats(rho, 3, "rho")))
        return p + self._c - self._o - rho[:, None] * self._e

    def parallel_singularity_measure(self, position, rho=None) -> float:
        """|det| of the unit leg directions, the rows of A normalised (Orthoglide §3.3,
        eq. 4a): 1 when the legs are orthogonal (the Orthoglide's isotropic
        configuration), 0 at a parallel singularity (det A = 0: the legs coplanar or
        parallel, where the platform moves with the drives locked and resists no
        force)."""
        a = self.parallel_jacobian(position, rho)
        return float(abs(np.linalg.det(a / np.linalg.norm(a, axis=1, keepdims=True))))

    def parallel_singularity_measure_batch(self, positions) -> np.ndarray:
        """:meth:`parallel_singularity_measure` for positions (N, 3); NaN where unreachable."""
        p = finite_array(positions, "positions", (-1, 3))
        rho, _ = self.inverse_kinematics_batch(p)
        a = p[:, None, :] + self._c[None] - self._o[None] - rho[:, :, None] * self._e[None]
        with np.errstate(invalid="ignore"):
            return np.abs(np.linalg.det(a / np.linalg.norm(a, axis=2, keepdims=True)))

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

    def jacobian(self, position, rho=None) -> np.ndarray:
        """J_m = B^-1 A (Orthoglide eq. 8), rhodot = J_m pdot. Raises SingularityError
        at a serial singularity (a leg perpendicular to its rail: B singular)."""
        a = self.parallel_jacobian(position, rho)
        b = np.einsum("ij,ij->i", a, self._e)
        if np.any(np.abs(b) <= 1e-9 * self._length):
            i = int(np.argmin(np.abs(b) / self._length))
            raise SingularityError(f"leg {self.leg_names[i]} is perpendicular to its rail (serial "
                                   "singularity, Orthoglide §3.3): J_m is unbounded")
        return a / b[:, None]

    def workspace_grid(self, points_per_axis: int = 11, theta_points: int = 13) -> np.ndarray:
        """A regular grid over the configured workspace cube: (N, 3) positions
        (``theta_points``: the planar machines' signature, unused)."""
        return cube_grid(self.workspace["center"], self.workspace["size"], points_per_axis)

    def condition_number_batch(self, positions) -> np.ndarray:
        """Condition numbers of J_m at positions (N, 3): NaN where unreachable."""
        return condition_numbers(self.jacobian_batch(positions))

    def jacobian_batch(self, positions) -> np.ndarray:
        """J_m for positions (N, 3): (N, 3, 3), NaN where unreachable."""
        p = np.asarray(positions, dtype=float)
        rho, _ = self.inverse_kinematics_batch(p)
        a = p[:, None, :] + self._c - self._o - rho[:, :, None] * self._e
        return a / np.einsum("nij,ij->ni", a, self._e)[:, :, None]

    # the task coordinates' rates are the twist here: q' = J_m x'
    task_jacobian_batch = jacobian_batch

    def jacobian_derivative(self, position, velocity, rho=None) -> np.ndarray:
        """dJ_m/dt along pdot. With a_i the leg vector and s_i = a_i . e_i:
        adot_i = pdot - rhodot_i e_i, Jdot[i] = adot_i / s_i - a_i (adot_i . e_i) / s_i^2."""
        v = np.array(finite_floats(velocity, 3, "velocity"))
        a = self.parallel_jacobian(position, rho)
        s = np.einsum("ij,ij->i", a, self._e)
        rhodot = (a @ v) / s
        adot = v - rhodot[:, None] * self._e
        sdot = np.einsum("ij,ij->i", adot, self._e)
        return adot / s[:, None] - a * (sdot / s**2)[:, None]

    def velocity_terms(self, position, velocity) -> tuple[list, list, list, list]:
        """(rho, rows of J_m, rhodot, Jdot_m pdot) as lists of floats for the dynamic
        model; see :func:`velocity_terms_kernel`."""
        rho, rows, rhodot, bias = self.velocity_terms_arrays(position, velocity)
        return rho.tolist(), rows.tolist(), rhodot.tolist(), bias.tolist()

    def velocity_terms_arrays(self, position, velocity) -> tuple:
        """:meth:`velocity_terms` as arrays (rho (3,), J_m (3, 3), rhodot, Jdot_m pdot).
        Raises UnreachablePoseError / SingularityError naming the leg. Compiled."""
        if len(position) != 3 or len(velocity) != 3:
            raise ValueError(f"velocity terms: position and velocity need 3 values each, got {len(position)} and {len(velocity)}")
        rho, rows, rhodot, bias, code, leg = velocity_terms_kernel(
            self._legs_a, position[0], position[1], position[2], velocity[0], velocity[1], velocity[2])
        if code != VT_OK:
            self.raise_velocity_terms_error(code, leg, position)
        return rho, rows, rhodot, bias

    def raise_velocity_terms_error(self, code: int, leg: int, position) -> None:
        """Raise the exception for a failure ``code`` of :func:`velocity_terms_kernel`."""
        raise velocity_terms_error(code, self.leg_names[leg], "position", position)

    def condition_number(self, position) -> float:
        return float(np.linalg.cond(self.jacobian(position)))

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
