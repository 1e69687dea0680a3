"""The forward kinematics of planar rail machines: n >= 3 prismatic-revolute-revolute
(PRR) legs (``rails.RailMachine`` with the task space PLANAR), and ARCHI's two-arm
force map.

Model (ARCHI paper, section 3; Sliding Star is the same family):

* leg i has a straight rail through ``rail_origin`` o_i with unit ``rail_direction``
  u_i; its carriage sits at A_i = o_i + q_i u_i (q_i is the drive position, m);
* a link of length L_i joins A_i to the platform point B_i = p + R(theta) b_i, where
  the pose x = (x, y, theta) is the position of the platform centre C and its angle;
* legs that share a platform point (ARCHI's B12 and B34) form pairs, which gives a
  closed-form forward model.

Inverse position (ARCHI §3.1 "inverse position relationship", generalised to any rail):
    w_i = B_i - o_i,  a_i = u_i . w_i,  q_i = a_i + sigma_i sqrt(L_i^2 - |w_i|^2 + a_i^2)
with the assembly mode sigma_i = +-1 (ARCHI: q1 = x12 - s1, q2 = x12 + s1, ...).

Velocity (ARCHI §3.2, J_v G xdot = J_q qdot): for every leg, with e_i = B_i - A_i,
    e_i . (pdot + thetadot E R b_i) = (e_i . u_i) qdot_i   =>   qdot = J_m xdot,
    J_m[i] = [e_i^T, e_i^T E R b_i] / (e_i . u_i),   E = rot(+90 deg).

Unlimited rotation: theta is any real number; forward kinematics returns the angle
on the revolution of the guess.

Each leg is one rail bar of the bar model in the plane z = 0 (``bars``,
MACHINE_MODEL.md), the platform moving in the twist components vx, vy, wz: the
inverse kinematics, velocity terms, J_m, its derivative and their batches are
``rails.RailMachine``'s (``bars`` kernels written once for every rail machine); the
forward kinematics below (``PlanarLeastSquaresFK``, "least_squares" in
``rails.FORWARD_SOLVERS``: the leg pairs' closed form, least squares with the exact
Hessian, the working-mode checks) reads the same bars.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from . import bars as B
from .bars import COL_A, COL_B, COL_BRANCH, COL_LENGTH, COL_U
from .errors import FieldError, KinematicsError, UnreachablePoseError
from .jit import kernel
from .machine import ForwardKinematicsResult
from .rotations import unwrap_to_kernel
from .task_space import PLANAR
from .validation import finite_array, finite_floats


# Forward kinematics switches from Gauss-Newton to Newton steps (exact Hessian) once a
# Gauss-Newton step is shorter than this (m + rad): inside the quadratic basin.
NEWTON_RADIUS = 1e-2


def solve3(a, b):
    """Solve a 3x3 system by Cramer's rule on Python floats (10x faster than LAPACK
    here): :func:`solve3_kernel` interpreted, for Python callers."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    x0, x1, x2, ok = solve3_kernel.py_func(a00, a01, a02, a10, a11, a12, a20, a21, a22, b[0], b[1], b[2])
    if not ok:
        raise np.linalg.LinAlgError("singular 3x3 system")
    return x0, x1, x2


class PlanarFKCode(IntEnum):
    """How a planar machine's forward kinematics ended (the compiled kernel returns it,
    the method turns it into the result's reason; FK_* below: the kernels' ints)."""
    CONVERGED = 0
    UNREACHABLE = 1         # two legs' carriages too far apart to close (the message names them)
    SINGULAR = 2
    NO_CONVERGENCE = 3
    ASSEMBLY = 4            # converged to another working mode
    PAIR = 5


FK_CONVERGED, FK_UNREACHABLE, FK_SINGULAR, FK_NO_CONVERGENCE, FK_ASSEMBLY, FK_PAIR = (int(c) for c in PlanarFKCode)
FK_TOL, FK_MAX_ITERATIONS = 1e-12, 50        # forward_kinematics' defaults: step (m, rad), iterations
# the description of each code but CONVERGED and UNREACHABLE (whose message names the legs)
FK_REASONS = {PlanarFKCode.SINGULAR: "singular configuration: Jacobian rank < 3",
              PlanarFKCode.NO_CONVERGENCE: "no convergence in {} iterations",
              PlanarFKCode.ASSEMBLY: "converged to another working mode (assembly branch)",
              PlanarFKCode.PAIR: "converged to another working mode (leg pair)"}


@kernel()
def solve3_kernel(a00, a01, a02, a10, a11, a12, a20, a21, a22, b0, b1, b2):
    """:func:`solve3` for the kernels: (x0, x1, x2, solvable)."""
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0 or not math.isfinite(det):
        return 0.0, 0.0, 0.0, False
    x0 = (b0 * c00 + b1 * (a02 * a21 - a01 * a22) + b2 * (a01 * a12 - a02 * a11)) / det
    x1 = (b0 * c01 + b1 * (a00 * a22 - a02 * a20) + b2 * (a02 * a10 - a00 * a12)) / det
    x2 = (b0 * c02 + b1 * (a01 * a20 - a00 * a21) + b2 * (a00 * a11 - a01 * a10)) / det
    return x0, x1, x2, True


@kernel("(float64[:, :], int64[:, :], float64[:], float64[:])")
def _closed_form_kernel(bars, pairs, sides, q):
    """Closed-form forward position (ARCHI §3.1): each shared platform point is the
    intersection of the circles of radius L about its two carriages, on the side of
    the working mode; the angle from the two points. ``bars``: the machine's
    (``RailMachine.bars``, z = 0). Returns (x, y, theta, code, i, j, d): code
    FK_UNREACHABLE with the legs i, j whose carriages, d m apart, cannot close."""
    px0 = py0 = px1 = py1 = 0.0
    for k in range(2):
        i, j, side = pairs[k, 0], pairs[k, 1], sides[k]
        aix, aiy = bars[i, COL_A] + q[i] * bars[i, COL_U], bars[i, COL_A + 1] + q[i] * bars[i, COL_U + 1]
        dx = bars[j, COL_A] + q[j] * bars[j, COL_U] - aix
        dy = bars[j, COL_A + 1] + q[j] * bars[j, COL_U + 1] - aiy
        d2 = dx * dx + dy * dy
        d = math.sqrt(d2)
        along = ((bars[i, COL_LENGTH] * bars[i, COL_LENGTH]) - (bars[j, COL_LENGTH] * bars[j, COL_LENGTH]) + d2) / (2.0 * d) if d > 0.0 else math.inf
        h2 = (bars[i, COL_LENGTH] * bars[i, COL_LENGTH]) - along * along
        if not h2 >= 0.0:
            return 0.0, 0.0, 0.0, FK_UNREACHABLE, i, j, d
        h = side * math.sqrt(h2)
        px, py = aix + (along * dx - h * dy) / d, aiy + (along * dy + h * dx) / d
        if k == 0:
            px0, py0 = px, py
        else:
            px1, py1 = px, py
    i1, i2 = pairs[0, 0], pairs[1, 0]
    b1x, b1y, b2x, b2y = bars[i1, COL_B], bars[i1, COL_B + 1], bars[i2, COL_B], bars[i2, COL_B + 1]
    theta = math.atan2(py1 - py0, px1 - px0) - math.atan2(b2y - b1y, b2x - b1x)
    c, s = math.cos(theta), math.sin(theta)
    return px0 - (c * b1x - s * b1y), py0 - (s * b1x + c * b1y), theta, FK_CONVERGED, 0, 0, 0.0


@kernel("(float64[:, :], int64[:, :], float64[:], float64[:], float64, float64, float64, float64, int64)")
def _forward_kinematics_kernel(bars, pairs, sides, q, ref_x, ref_y, ref_th, tol, max_iterations):
    """The solver of :meth:`PlanarLeastSquaresFK.solve` (see there), compiled.
    Returns (x, y, theta, code, iterations, residual_m, i, j, d); (i, j, d) name the
    bars of an unreachable closed form."""
    n = bars.shape[0]
    if pairs.shape[0] >= 2:
        x, y, th, code, i, j, d = _closed_form_kernel(bars, pairs, sides, q)
        if code != FK_CONVERGED:
            return 0.0, 0.0, 0.0, code, 0, math.inf, i, j, d
        th = unwrap_to_kernel(th, ref_th)
    else:
        x, y, th = ref_x, ref_y, ref_th
    use_hessian = False
    previous_size = math.inf
    converged = False
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        c, s = math.cos(th), math.sin(th)
        r = (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
        # Newton on C = 1/2 sum f_i^2, f_i = |e_i| - L_i, e_i = p + R b_i - A_i:
        # grad f_i = g_i = [e^T, e^T E R b] / |e|; its Hessian is h_i h_i^T / |e| with
        # h_i = [n^T, n^T E R b], n = E e / |e|, plus -e.(R b)/|e| in (theta, theta).
        # When the drives disagree (model error) Gauss-Newton alone converges only
        # linearly (~0.9 per step); the exact Hessian restores quadratic convergence.
        # It is accumulated only then, inside the basin (see NEWTON_RADIUS).
        # J^T J, J^T f and the Hessian term in one pass over the bars, each row made
        # on the fly (distribution.gram_rows would need the rows as an array first)
        a00 = a01 = a02 = a11 = a12 = a22 = r0 = r1 = r2 = 0.0
        h00 = h01 = h02 = h11 = h12 = h22 = 0.0
        misfit = 0.0
        for k in range(n):
            ex, ey, _, rbx, rby, _ = B.bar_vector(bars, k, x, y, 0.0, r, q)
            dist = math.sqrt(ex * ex + ey * ey)
            f = dist - B.bar_length(bars, k, q)
            gx, gy, gt = ex / dist, ey / dist, (ey * rbx - ex * rby) / dist
            a00 += gx * gx
            a01 += gx * gy
            a02 += gx * gt
            a11 += gy * gy
            a12 += gy * gt
            a22 += gt * gt
            r0 += gx * f
            r1 += gy * f
            r2 += gt * f
            if abs(f) > misfit:
                misfit = abs(f)
            if use_hessian:
                w = f / dist
                nt = gx * rbx + gy * rby          # n . (E R b) with n = (-gy, gx)
                h00 += w * gy * gy
                h01 -= w * gy * gx
                h02 -= w * gy * nt
                h11 += w * gx * gx
                h12 += w * gx * nt
                h22 += w * (nt * nt - (ex * rbx + ey * rby))
        dx, dy, dth, ok = solve3_kernel(a00, a01, a02, a01, a11, a12, a02, a12, a22, r0, r1, r2)
        if not ok:
            return 0.0, 0.0, 0.0, FK_SINGULAR, iteration, math.inf, 0, 0, 0.0
        if use_hessian:
            nx_, ny_, nt_, ok = solve3_kernel(a00 + h00, a01 + h01, a02 + h02, a01 + h01, a11 + h11, a12 + h12,
                                               a02 + h02, a12 + h12, a22 + h22, r0, r1, r2)
            if ok and nx_ * r0 + ny_ * r1 + nt_ * r2 > 0.0:     # a descent direction
                dx, dy, dth = nx_, ny_, nt_
        x -= dx
        y -= dy
        th -= dth
        size = abs(dx) + abs(dy) + abs(dth)
        # converged: a step below tol, or a step below 1e-6 that contracted
        # quadratically (1000x smaller than the last): the next would be ~1e-12
        if size < tol or (size < 1e-6 and size < 1e-3 * previous_size):
            converged = True
            break
        previous_size = size
        use_hessian = size < NEWTON_RADIUS and misfit > 1e-9
    if not converged:
        return 0.0, 0.0, 0.0, FK_NO_CONVERGENCE, max_iterations, math.nan, 0, 0, 0.0
    th = unwrap_to_kernel(th, ref_th)                              # on the guess's revolution
    # residual at the returned pose, and the working mode (see PlanarLeastSquaresFK)
    c, s = math.cos(th), math.sin(th)
    r = (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
    residual = 0.0
    e = np.empty((n, 2))
    for k in range(n):
        ex, ey, _, _, _, _ = B.bar_vector(bars, k, x, y, 0.0, r, q)
        e[k, 0], e[k, 1] = ex, ey
        residual = max(residual, abs(math.sqrt(ex * ex + ey * ey) - B.bar_length(bars, k, q)))
        if (ex * bars[k, COL_U] + ey * bars[k, COL_U + 1]) * bars[k, COL_BRANCH] > 0.0:
            return 0.0, 0.0, 0.0, FK_ASSEMBLY, iteration, residual, 0, 0, 0.0
    for k in range(pairs.shape[0]):
        # the side of carriage i's link its pair's carriage j is on: a pair shares its
        # platform point, so A_j - A_i = e_i - e_j
        i, j = pairs[k, 0], pairs[k, 1]
        if ((e[i, 0] - e[j, 0]) * e[i, 1] - (e[i, 1] - e[j, 1]) * e[i, 0]) * sides[k] < 0.0:
            return 0.0, 0.0, 0.0, FK_PAIR, iteration, residual, 0, 0, 0.0
    return x, y, th, FK_CONVERGED, iteration, residual, 0, 0, 0.0


@kernel("(float64[:, :], int64[:, :], float64[:], float64[:, :], float64[:, :], float64, int64)")
def _forward_kinematics_batch_kernel(bars, pairs, sides, q, guesses, tol, max_iterations):
    """_forward_kinematics_kernel on every row of ``q`` (N, n) from the row of
    ``guesses``: the poses (N, 3), NaN where the solve failed, and the codes (N,)."""
    rows = q.shape[0]
    poses = np.full((rows, 3), np.nan)
    codes = np.empty(rows, dtype=np.int64)
    for r in range(rows):
        x, y, th, code, _, _, _, _, _ = _forward_kinematics_kernel(
            bars, pairs, sides, q[r], guesses[r, 0], guesses[r, 1], guesses[r, 2], tol, max_iterations)
        codes[r] = code
        if code == FK_CONVERGED:
            poses[r, 0], poses[r, 1], poses[r, 2] = x, y, th
    return poses, codes


forward_kinematics_kernel = _forward_kinematics_kernel      # for compiled callers (dynamics.planar_encoder_state_kernel)


class PlanarLeastSquaresFK:
    """The forward kinematics of a planar rail machine (``rails.FORWARD_SOLVERS``
    "least_squares"): Gauss-Newton least squares over all n legs, started from the
    leg pairs' closed form where the legs pair up (ARCHI), with the working-mode
    checks. Built once per machine (constant data: the pairs and their sides at home)."""

    def __init__(self, machine):
        if machine.task_space is not PLANAR:
            raise FieldError("forward", f"least_squares solves a planar machine (x, y, theta), not a "
                                        f"{machine.task_space.name} one")
        self.machine = machine
        self.pairs = machine.leg_pairs
        self.bars = machine.bars
        # Working mode: the assembly branch sigma_i of every leg (which of the two
        # carriage positions on the rail), and for paired legs which of the two circle
        # intersections the shared point is, taken at home. (The side of its rail a
        # lone leg's platform point lies on is a property of the pose, not a mode.)
        o, u = machine.rail_origins, machine.rail_directions
        home = machine.home
        q_home = machine.inverse_kinematics(home, check_limits=False)
        points = platform_points(machine, home)
        sides = []
        for i, j in self.pairs:
            a_i, a_j = o[i] + q_home[i] * u[i], o[j] + q_home[j] * u[j]
            d, pt = a_j - a_i, points[i] - a_i
            sides.append(math.copysign(1.0, d[0] * pt[1] - d[1] * pt[0]))
        self.pairs_array = np.array(self.pairs, dtype=np.int64).reshape(-1, 2)
        self.sides = np.array(sides, dtype=float)

    def closed_form(self, q) -> np.ndarray:
        """Closed-form forward position (ARCHI §3.1) from the two leg pairs.

        Each shared platform point is the intersection of the two circles of radius L
        about its carriages, on the side given by the working mode. (The seed text
        pairs q1 with q3; the consistent formula pairs q1 with q2 and q3 with q4:
        x12 = (q1 + q2)/2, y12 = -sqrt(L^2 - (q2 - q1)^2/4) for ARCHI.)
        """
        m = self.machine
        if not self.pairs:
            raise ValueError(f"machine {m.name!r} has no leg pairs sharing a platform point: "
                             "no closed-form forward model; use forward_kinematics")
        qs = np.array(finite_floats(q, m.n_legs, "q"))
        x, y, th, code, i, j, d = _closed_form_kernel(self.bars, self.pairs_array, self.sides, qs)
        if code:
            raise UnreachablePoseError(self._unreachable_message(i, j, d))
        return np.array([x, y, th])

    def _unreachable_message(self, i: int, j: int, d: float) -> str:
        m, length = self.machine, self.bars[:, B.COL_LENGTH]
        return (f"legs {m.leg_names[i]}, {m.leg_names[j]}: carriages {d:.6g} m apart cannot close "
                f"with link lengths {length[i]:.6g} m and {length[j]:.6g} m")

    def solve(self, q, guess=None, tol: float = FK_TOL,
              max_iterations: int = FK_MAX_ITERATIONS) -> ForwardKinematicsResult:
        """Pose from drive positions: Gauss-Newton least squares over all n legs.

        Started from the closed form where the legs pair up (ARCHI), else from
        ``guess`` (default: home pose). Footnote 5 of ARCHI §3.1 suggests the iterative
        scheme x_{n+1} = x_n + J (q_d - q_n); we minimise sum_i (|B_i - A_i| - L_i)^2,
        which stays defined away from the solution. Converged when a step is below
        ``tol`` (m, rad); with drive positions that no pose matches (model error) this
        is the least-squares pose, and ``residual_m`` (the largest leg-length misfit at
        the returned pose) says how far off they are. The angle is returned on the
        revolution of ``guess`` (unlimited rotation). The result's pose is NaN and
        ``converged`` False if the solve fails or lands on another working mode.
        Compiled (:func:`_forward_kinematics_kernel`); ~3 us a call.
        """
        qs = np.array(finite_floats(q, self.machine.n_legs, "q"))
        ref = self.machine.home if guess is None else finite_floats(guess, 3, "guess")
        x, y, th, code, iterations, residual, i, j, d = _forward_kinematics_kernel(
            self.bars, self.pairs_array, self.sides, qs, float(ref[0]), float(ref[1]), float(ref[2]),
            tol, max_iterations)
        if code == FK_CONVERGED:
            return ForwardKinematicsResult(np.array([x, y, th]), True, int(iterations), float(residual))
        reason = self._unreachable_message(i, j, d) if code == FK_UNREACHABLE else FK_REASONS[code]
        if code == FK_NO_CONVERGENCE:
            reason = reason.format(max_iterations)
        return ForwardKinematicsResult(np.full(3, np.nan), False, int(iterations), float(residual), reason)

    def floats(self, q, guess=None) -> tuple[float, float, float]:
        """:meth:`solve` on the per-cycle path: ``q`` n finite floats (finiteness
        unchecked: the caller checked it), the pose as a tuple; a failed solve
        raises KinematicsError with the result's reason (UnreachablePoseError for
        legs that cannot close)."""
        if len(q) != self.machine.n_legs:
            raise FieldError("q", f"expected {self.machine.n_legs} drive positions, got {len(q)}")
        ref = self.machine.home if guess is None else guess
        x, y, th, code, _, _, i, j, d = _forward_kinematics_kernel(
            self.bars, self.pairs_array, self.sides, np.asarray(q, dtype=float), float(ref[0]), float(ref[1]),
            float(ref[2]), FK_TOL, FK_MAX_ITERATIONS)
        if code == FK_CONVERGED:
            return x, y, th
        if code == FK_UNREACHABLE:
            raise UnreachablePoseError(self._unreachable_message(i, j, d))
        raise KinematicsError(FK_REASONS[code].format(FK_MAX_ITERATIONS))

    def batch(self, q, guesses=None, tol: float = FK_TOL,
              max_iterations: int = FK_MAX_ITERATIONS) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`solve` for q of shape (N, n): the same compiled solver on every row
        (closed-form start where there is one, else the row of ``guesses`` (N, 3) or
        the home pose; its step criteria, Hessian gate and working-mode checks).
        Returns (poses (N, 3), converged mask (N,)); failed rows are NaN."""
        q = finite_array(q, "q", (-1, self.machine.n_legs))
        n = q.shape[0]
        guesses = (np.tile(self.machine.home, (n, 1)) if guesses is None
                   else finite_array(guesses, "guesses", (n, 3)))
        poses, codes = _forward_kinematics_batch_kernel(self.bars, self.pairs_array, self.sides,
                                                        np.ascontiguousarray(q), np.ascontiguousarray(guesses),
                                                        float(tol), int(max_iterations))
        return poses, codes == FK_CONVERGED


def platform_points(machine, pose) -> np.ndarray:
    """World coordinates of a planar machine's platform points B_i = p + R b_i, (n, 2)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    b = machine.bars[:, B.COL_B:B.COL_B + 2]
    out = np.empty_like(b)
    out[:, 0] = pose[0] + c * b[:, 0] - s * b[:, 1]
    out[:, 1] = pose[1] + s * b[:, 0] + c * b[:, 1]
    return out


def pair_force_map(machine, pose) -> tuple[np.ndarray, np.ndarray]:
    """For a planar machine of two leg pairs (ARCHI §4.3): (M, J_f).

    M = (J_v^-1 J_q)^T maps the forces (f1x, f1y, f2x, f2y) applied at the two
    shared platform points to drive forces, f_d = M f_pts (the seed text writes
    J_x^-1 for the 4x4 J_v). J_f maps (f1, f2) to (f_x, f_y, m_z, internal force
    (f1 - f2) . n) with n the unit vector from point 1 to point 2.
    """
    pairs = getattr(machine, "leg_pairs", [])
    if machine.task_space is not PLANAR or len(pairs) != 2 or machine.n_legs != 4:
        raise ValueError(f"machine {machine.name!r}: the two-arm model needs exactly two pairs "
                         "of legs sharing two platform points (ARCHI)")
    pose = np.asarray(pose, dtype=float)
    q = machine.inverse_kinematics(pose, check_limits=False)
    u = machine.bars[:, B.COL_U:B.COL_U + 2]
    pts = platform_points(machine, pose)
    e = pts - machine.bars[:, B.COL_A:B.COL_A + 2] - q[:, None] * u     # e_i = B_i - A_i
    jv = np.zeros((4, 4))
    jq = np.zeros((4, 4))
    for k, pair in enumerate(pairs):
        for leg in pair:
            jv[leg, 2 * k:2 * k + 2] = e[leg]
            jq[leg, leg] = e[leg] @ u[leg]
    force_map = np.linalg.solve(jv, jq).T
    (i1, _), (i2, _) = pairs
    r1 = pts[i1] - pose[:2]
    r2 = pts[i2] - pose[:2]
    n = (pts[i2] - pts[i1]) / np.linalg.norm(pts[i2] - pts[i1])
    jf = np.array([
        [1.0, 0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0, 1.0],
        [-r1[1], r1[0], -r2[1], r2[0]],
        [n[0], n[1], -n[0], -n[1]],
    ])
    return force_map, jf
