"""Gough-Stewart platform used as a metrology sensor (MoM3 §4.2, §5.2).

Six struts of measured length l_i join base points A_i (base frame, z = 0) to plate
points b_i (plate frame). The pose of the travelling plate is its centre E_h
(position p, m) and its rotation R (base <- plate).

* Inverse model (struts): l_i = |p + R b_i - A_i|.
* Inverse Jacobian (MoM3 eq. 2-3): ldot = J_h^-1 [pdot; omega] with rows
  [u_i^T, (u_i x B_iE_h)^T], u_i = A_iB_i / l_i. The seed prints -u_i x B_iE_h; with
  omega the angular velocity in the base frame the finite-difference check of the
  tests gives the sign used here (u_i x B_iE_h = (R b_i) x u_i).
* Tool Jacobian (MoM3 eq. 10-11): dp_t = J_t dl, J_t = J_hP - [E_hE_t]x J_hR.
* Direct kinematic model: Newton-Raphson on the six strut equations, warm-started
  from the previous pose, the rotation updated on SO(3) (R <- exp([dw]x) R, not by
  adding angle increments), with tolerance, iteration cap, divergence detection and
  a check of the assembly branch (the mirror pose below the base plane has the same
  strut lengths). The result reports iterations, Jacobian evaluations and residual;
  on failure its pose is NaN and ``reason`` says why - never a wrong pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .jit import kernel
from .rotations import exp_so3_floats, exp_so3_kernel, mul3, mul3_kernel
from .validation import finite_array, finite_floats


def validate_rotation(value, name: str) -> list[float]:
    """A rotation matrix as 9 row-major floats; refuses non-finite values, a wrong
    shape, and matrices that are not rotations (|R^T R - I| > 1e-6 or det <= 0): six
    strut lengths cannot see a non-rigid plate, so a distorted guess would survive."""
    rot = np.asarray(value, dtype=float)
    if rot.shape != (3, 3) or not np.isfinite(rot).all():
        raise ValueError(f"{name}: expected a finite 3 x 3 rotation matrix, got {value!r}")
    if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) <= 0.0:
        raise ValueError(f"{name}: not a rotation matrix (R^T R != I or det(R) <= 0): {rot.tolist()}")
    return rot.ravel().tolist()


@dataclass
class GoughDKMResult:
    """Outcome of a direct kinematic solve (pose NaN unless converged)."""

    position: np.ndarray
    rotation: np.ndarray
    converged: bool
    iterations: int
    jacobian_evaluations: int
    residual_m: float
    reason: str = ""
    jacobian: np.ndarray | None = None   # J_h of the last linearisation, (6, 6) (for warm starts)


def mom3_points(r_base: float, r_plate: float, alpha_base_rad: float, alpha_plate_rad: float,
                plate_line_offset_rad: float = math.pi / 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Joint centres of the MoM3 parametrisation (§5.2, Figure 11).

    Three lines through the centres, 120 deg apart; the two base points of line k lie
    at +-alpha_base/2 about it on radius r_base. The plate lines are turned by
    ``plate_line_offset`` (60 deg: the classical 6-6 arrangement where every base pair
    feeds two different plate pairs) with points at +-alpha_plate/2 on radius r_plate.
    Strut 2k joins base point gamma_k + alpha_b/2 to plate point gamma_k + offset - alpha_tp/2,
    strut 2k+1 joins gamma_k - alpha_b/2 to gamma_k - offset + alpha_tp/2.
    Returns (base points (6, 3), plate points (6, 3)).
    """
    base, plate = [], []
    for k in range(3):
        g = 2.0 * math.pi * k / 3.0
        for sign in (1.0, -1.0):
            ab = g + sign * alpha_base_rad / 2.0
            ap = g + sign * (plate_line_offset_rad - alpha_plate_rad / 2.0)
            base.append((r_base * math.cos(ab), r_base * math.sin(ab), 0.0))
            plate.append((r_plate * math.cos(ap), r_plate * math.sin(ap), 0.0))
    return np.array(base), np.array(plate)


@kernel()
def strut_vector(legs, i, px, py, pz, r):
    """Strut i's vector l_i = p + R b_i - A_i (MoM3 eq. 1's closure) at the plate pose
    (p, R), ``r`` the row-major 9-tuple of R; ``legs`` rows (A_i, b_i). Returns
    (l_x, l_y, l_z, (R b_i)_x, (R b_i)_y, (R b_i)_z)."""
    bx, by, bz = legs[i, 3], legs[i, 4], legs[i, 5]
    rbx = r[0] * bx + r[1] * by + r[2] * bz
    rby = r[3] * bx + r[4] * by + r[5] * bz
    rbz = r[6] * bx + r[7] * by + r[8] * bz
    return px + rbx - legs[i, 0], py + rby - legs[i, 1], pz + rbz - legs[i, 2], rbx, rby, rbz


@kernel()
def inverse_jacobian_into(legs, px, py, pz, r, jinv):
    """J_h^-1 (MoM3 eq. 2-3) into ``jinv`` (6, 6): rows [u_i, (R b_i) x u_i], u_i the
    unit vector of strut i, at the plate pose (p, R row-major 9-tuple)."""
    for i in range(6):
        lx, ly, lz, rbx, rby, rbz = strut_vector(legs, i, px, py, pz, r)
        n = math.sqrt(lx * lx + ly * ly + lz * lz)
        ux, uy, uz = lx / n, ly / n, lz / n
        jinv[i, 0], jinv[i, 1], jinv[i, 2] = ux, uy, uz
        jinv[i, 3] = rby * uz - rbz * uy
        jinv[i, 4] = rbz * ux - rbx * uz
        jinv[i, 5] = rbx * uy - rby * ux


@kernel()
def invert6_into(a, out) -> bool:
    """out = a^-1 for a 6 x 6 matrix by Gauss-Jordan elimination with partial pivoting
    (``a`` is overwritten); False when a pivot vanishes (singular to machine precision).
    Inline: a LAPACK call per solve costs more than the elimination itself."""
    n = 6
    for i in range(n):
        for j in range(n):
            out[i, j] = 1.0 if i == j else 0.0
    scale = 0.0
    for i in range(n):
        for j in range(n):
            scale = max(scale, abs(a[i, j]))
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if not abs(a[pivot, col]) > 1e-14 * scale:
            return False
        if pivot != col:
            for j in range(n):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
                out[col, j], out[pivot, j] = out[pivot, j], out[col, j]
        inv_p = 1.0 / a[col, col]
        for j in range(n):
            a[col, j] *= inv_p
            out[col, j] *= inv_p
        for row in range(n):
            if row != col:
                f = a[row, col]
                if f != 0.0:
                    for j in range(n):
                        a[row, j] -= f * a[col, j]
                        out[row, j] -= f * out[col, j]
    return True


@kernel()
def jacobian_into(legs, px, py, pz, r, out):
    """J_h = (J_h^-1)^-1 (MoM3 eq. 1) into ``out`` (6, 6); False where J_h^-1 is
    singular (``out`` then undefined)."""
    jinv = np.empty((6, 6))
    inverse_jacobian_into(legs, px, py, pz, r, jinv)
    return invert6_into(jinv, out)


@kernel("(float64[:, :], float64, float64, float64, float64, float64, float64, float64, float64, float64, float64, float64, float64)")
def strut_lengths_kernel(legs, px, py, pz, r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """IKM_GP (MoM3 §5.2): l_i = |p + R b_i - A_i| for ``legs`` rows (A_i, b_i), (n, 6),
    at the pose (p, R row-major); the per-reading form of :meth:`GoughPlatform.strut_lengths`."""
    r = (r00, r01, r02, r10, r11, r12, r20, r21, r22)
    out = np.empty(legs.shape[0])
    for i in range(legs.shape[0]):
        lx, ly, lz, _, _, _ = strut_vector(legs, i, px, py, pz, r)
        out[i] = math.sqrt(lx * lx + ly * ly + lz * lz)
    return out


@kernel("(float64[:, :], float64, float64, float64, float64, float64, float64, float64, float64, float64, float64, float64, float64)")
def _jacobian_kernel(legs, px, py, pz, r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """J_h = (J_h^-1)^-1 (MoM3 eq. 1) at the plate pose (p, R). Raises
    numpy.linalg.LinAlgError where J_h^-1 is singular."""
    jinv = np.empty((6, 6))
    inverse_jacobian_into(legs, px, py, pz, (r00, r01, r02, r10, r11, r12, r20, r21, r22), jinv)
    return np.linalg.inv(jinv)


@kernel("(float64[:, :], float64[:, :], float64[:, :], float64[:, :])")
def strut_lengths_batch_kernel(legs, positions, rotations, out):
    """strut lengths (MoM3 §5.2) of N poses (``rotations`` rows row-major) into ``out`` (N, n)."""
    for n in range(positions.shape[0]):
        r = (rotations[n, 0], rotations[n, 1], rotations[n, 2], rotations[n, 3], rotations[n, 4],
             rotations[n, 5], rotations[n, 6], rotations[n, 7], rotations[n, 8])
        for i in range(legs.shape[0]):
            lx, ly, lz, _, _, _ = strut_vector(legs, i, positions[n, 0], positions[n, 1], positions[n, 2], r)
            out[n, i] = math.sqrt(lx * lx + ly * ly + lz * lz)


@kernel("(float64[:, :], float64[:, :], float64[:, :], float64[:, :, :])")
def inverse_jacobian_batch_kernel(legs, positions, rotations, out):
    """J_h^-1 (MoM3 eq. 2-3) of N poses (``rotations`` rows row-major) into ``out`` (N, 6, 6)."""
    for n in range(positions.shape[0]):
        r = (rotations[n, 0], rotations[n, 1], rotations[n, 2], rotations[n, 3], rotations[n, 4],
             rotations[n, 5], rotations[n, 6], rotations[n, 7], rotations[n, 8])
        inverse_jacobian_into(legs, positions[n, 0], positions[n, 1], positions[n, 2], r, out[n])


DKM_CONVERGED, DKM_NO_CONVERGENCE, DKM_DIVERGED_LIMIT, DKM_DIVERGED_GROWTH, DKM_SINGULAR = range(5)


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:, :], boolean, float64, int64, float64)")
def dkm_newton_kernel(legs, target, p, rot, jh, have_jh, tol_m, max_iterations, divergence_limit):
    """The DKM iteration of :meth:`GoughPlatform.direct_kinematics` (MoM3 §6.3), compiled:
    Newton-Raphson on the strut residuals r_i = l_i - |p + R b_i - A_i|, the step
    [dp; dw] = J_h r, p += dp, R <- exp([dw]x) R; J_h (``jh``, valid when ``have_jh``)
    re-evaluated when an iteration gains less than three orders of magnitude.
    ``p`` (3,), ``rot`` (9, row-major) and ``jh`` (6, 6) are updated in place. Returns
    (code, iterations, evaluations, residual, have_jh); code DKM_CONVERGED (every
    residual <= tol_m), DKM_NO_CONVERGENCE, DKM_DIVERGED_LIMIT (residual above
    ``divergence_limit``), DKM_DIVERGED_GROWTH (grew twice in a row), DKM_SINGULAR."""
    px, py, pz = p[0], p[1], p[2]
    r = (rot[0], rot[1], rot[2], rot[3], rot[4], rot[5], rot[6], rot[7], rot[8])
    res = np.empty(6)
    evaluations = 0
    previous = math.inf
    growth = 0
    residual = math.inf
    code = DKM_NO_CONVERGENCE
    iterations = max_iterations
    for iteration in range(max_iterations + 1):
        residual = 0.0
        for i in range(6):
            lx, ly, lz, _, _, _ = strut_vector(legs, i, px, py, pz, r)
            res[i] = target[i] - math.sqrt(lx * lx + ly * ly + lz * lz)
            if not abs(res[i]) <= residual:       # (NaN propagates)
                residual = abs(res[i])
        if residual <= tol_m:
            code, iterations = DKM_CONVERGED, iteration
            break
        if iteration == max_iterations:
            break
        if not math.isfinite(residual) or residual > divergence_limit:
            code, iterations = DKM_DIVERGED_LIMIT, iteration
            break
        growth = growth + 1 if residual > previous else 0
        if growth >= 2:
            code, iterations = DKM_DIVERGED_GROWTH, iteration
            break
        if not have_jh or residual > 1e-3 * previous:
            evaluations += 1
            if not jacobian_into(legs, px, py, pz, r, jh):
                code, iterations = DKM_SINGULAR, iteration
                break
            have_jh = True
        previous = residual
        dx = dy = dz = wx = wy = wz = 0.0
        for j in range(6):
            dx += jh[0, j] * res[j]
            dy += jh[1, j] * res[j]
            dz += jh[2, j] * res[j]
            wx += jh[3, j] * res[j]
            wy += jh[4, j] * res[j]
            wz += jh[5, j] * res[j]
        px, py, pz = px + dx, py + dy, pz + dz
        r = mul3_kernel(exp_so3_kernel(wx, wy, wz), r)
    p[0], p[1], p[2] = px, py, pz
    for k in range(9):
        rot[k] = r[k]
    return code, iterations, evaluations, residual, have_jh


DKM_BAD_LENGTHS = 5


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:], float64[:], boolean, float64[:, :], boolean, "
        "float64, int64, float64, float64[:], float64[:])")
def dkm_warm_step_kernel(legs, target, p1, r1, p0, r0, has_previous, jh, have_jh, tol_m, max_iterations,
                         divergence_limit, p, rot):
    """One solve of a warm-starting solver (GoughDKMSolver.solve), compiled: the guess
    extrapolated from the last two solutions (p1, R1) and (p0, R0) when
    ``has_previous`` (p = 2 p1 - p0; R = exp(w) R1 with w the rotation vector of
    R1 R0^T, exact to O(w^3)), else (p1, R1); then dkm_newton_kernel into ``p`` and
    ``rot``. DKM_BAD_LENGTHS (nothing solved) when a length is not finite and > 0."""
    for i in range(6):
        if not (0.0 < target[i] < math.inf):
            return DKM_BAD_LENGTHS, 0, 0, math.inf, have_jh
    if has_previous:
        for k in range(3):
            p[k] = 2.0 * p1[k] - p0[k]
        b = (r1[0], r1[1], r1[2], r1[3], r1[4], r1[5], r1[6], r1[7], r1[8])
        d = mul3_kernel(b, (r0[0], r0[3], r0[6], r0[1], r0[4], r0[7], r0[2], r0[5], r0[8]))
        g = mul3_kernel(exp_so3_kernel(0.5 * (d[7] - d[5]), 0.5 * (d[2] - d[6]), 0.5 * (d[3] - d[1])), b)
        for k in range(9):
            rot[k] = g[k]
    else:
        p[:] = p1
        rot[:] = r1
    return dkm_newton_kernel(legs, target, p, rot, jh, have_jh, tol_m, max_iterations, divergence_limit)


@kernel("(float64[:, :], float64[:, :], float64[:, :], float64[:, :], float64, int64, float64, float64, "
        "float64[:, :], float64[:, :], boolean[:], int64[:])")
def dkm_batch_kernel(legs, lengths, guess_p, guess_r, tol_m, max_iterations, divergence_limit, home_det_sign,
                     p_out, r_out, ok, iterations):
    """dkm_newton_kernel on every row of ``lengths`` (N, 6) from its guess (``guess_r``
    rows row-major), with the branch checks of GoughPlatform._finish: the plate above
    the base plane and not flipped, and for a solve that travelled (re-linearised, or
    more than two steps) the sign of det(J_h^-1) at home. Rows that failed are NaN."""
    jh = np.empty((6, 6))
    jinv = np.empty((6, 6))
    for n in range(lengths.shape[0]):
        p, rot = p_out[n], r_out[n]
        p[:] = guess_p[n]
        rot[:] = guess_r[n]
        code, its, evaluations, _, _ = dkm_newton_kernel(legs, lengths[n], p, rot, jh, False, tol_m,
                                                         max_iterations, divergence_limit)
        good = code == DKM_CONVERGED and p[2] > 0.0 and rot[8] > 0.0
        if good and (evaluations > 0 or its > 2):
            inverse_jacobian_into(legs, p[0], p[1], p[2], (rot[0], rot[1], rot[2], rot[3], rot[4], rot[5],
                                                             rot[6], rot[7], rot[8]), jinv)
            good = np.linalg.det(jinv) * home_det_sign > 0.0
        ok[n] = good
        iterations[n] = its
        if not good:
            p[:] = math.nan
            rot[:] = math.nan


@dataclass
class GoughPlatform:
    """A 6-strut Gough platform; geometry in its base frame (see module docstring)."""

    base_points: np.ndarray
    plate_points: np.ndarray
    strut_limits: tuple[float, float] = (0.0, math.inf)
    home_position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = "gough"

    def __post_init__(self):
        self.base_points = finite_array(self.base_points, "base_points", (6, 3))
        self.plate_points = finite_array(self.plate_points, "plate_points", (6, 3))
        self.home_position = finite_array(self.home_position, "home_position", (3,))
        if not self.home_position[2] > 0.0:
            raise ValueError("home_position: the plate must be above the base plane (z > 0), "
                             f"got z = {self.home_position[2]}")
        self._lo, self._hi = float(self.strut_limits[0]), float(self.strut_limits[1])
        self._divergence_limit = 10.0 * max(1.0, self._hi - self._lo if math.isfinite(self._hi) else 1.0)
        # the struts as rows (A_i, b_i) for the compiled kernels
        self._legs_a = np.ascontiguousarray(np.hstack([self.base_points, self.plate_points]))
        self._home_det_sign = math.copysign(
            1.0, float(np.linalg.det(self.inverse_jacobian(self.home_position, np.eye(3)))))

    # ------------------------------------------------------------ inverse model
    def strut_lengths(self, position, rotation) -> np.ndarray:
        """l_i = |p + R b_i - A_i| (m); strut_lengths_kernel."""
        p, r = np.asarray(position, dtype=float), np.asarray(rotation, dtype=float)
        return strut_lengths_kernel(self._legs_a, p[0], p[1], p[2], *r.ravel().tolist())

    def strut_lengths_batch(self, positions, rotations) -> np.ndarray:
        """Strut lengths for (N, 3) positions and (N, 3, 3) rotations: (N, 6)."""
        positions, rotations = self._pose_rows(positions, rotations)
        out = np.empty((positions.shape[0], 6))
        strut_lengths_batch_kernel(self._legs_a, positions, rotations, out)
        return out

    @staticmethod
    def _pose_rows(positions, rotations) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) positions and (N, 9) row-major rotations, contiguous writable float64
        (the kernels' signature; a read-only input is copied)."""
        positions = np.require(np.reshape(positions, (-1, 3)), float, ["C", "W"])
        return positions, np.require(np.reshape(rotations, (positions.shape[0], 9)), float, ["C", "W"])

    def within_strut_limits(self, lengths) -> np.ndarray:
        lengths = np.asarray(lengths)
        return np.all((lengths >= self._lo) & (lengths <= self._hi), axis=-1)

    # ---------------------------------------------------------------- jacobians
    def inverse_jacobian(self, position, rotation) -> np.ndarray:
        """J_h^-1 (6 x 6), MoM3 eq. 2-3: rows [u_i^T, ((R b_i) x u_i)^T]."""
        return self.inverse_jacobian_batch(np.asarray(position, dtype=float)[None],
                                           np.asarray(rotation, dtype=float)[None])[0]

    def jacobian_rows(self, p, r) -> list[list]:
        """:meth:`jacobian` for the per-cycle path: J_h (MoM3 eq. 1) as 6 rows of 6
        floats, ``p`` 3 floats, ``r`` a row-major 9-tuple; unchecked. Compiled
        (:func:`_jacobian_kernel`): ~3 us against ~20 us with numpy.
        Raises numpy.linalg.LinAlgError at a singular pose."""
        return _jacobian_kernel(self._legs_a, p[0], p[1], p[2], *r).tolist()

    def inverse_jacobian_batch(self, positions, rotations) -> np.ndarray:
        """J_h^-1 for N poses: (N, 6, 6); inverse_jacobian_batch_kernel."""
        positions, rotations = self._pose_rows(positions, rotations)
        out = np.empty((positions.shape[0], 6, 6))
        inverse_jacobian_batch_kernel(self._legs_a, positions, rotations, out)
        return out

    def jacobian(self, position, rotation) -> np.ndarray:
        """J_h (6 x 6): [dp; dr] = J_h dl (MoM3 eq. 1), the inverse of eq. 2."""
        return np.linalg.inv(self.inverse_jacobian(position, rotation))

    def tool_jacobian(self, position, rotation, tool_offset) -> np.ndarray:
        """J_t (3 x 6), MoM3 eq. 10-11: J_t = J_hP - [E_hE_t]x J_hR.

        ``tool_offset`` is E_hE_t in the plate frame (eq. 4), rotated to the base frame.
        """
        jac = self.jacobian(position, rotation)
        lever = np.asarray(rotation) @ np.asarray(tool_offset, dtype=float)
        lx, ly, lz = lever
        skew = np.array([[0.0, -lz, ly], [lz, 0.0, -lx], [-ly, lx, 0.0]])
        return jac[:3] - skew @ jac[3:]

    # ------------------------------------------------------------- direct model
    @staticmethod
    def _validate_lengths(lengths) -> list[float]:
        values = finite_floats(lengths, 6, "strut lengths")
        if min(values) <= 0.0:
            raise ValueError(f"strut lengths: must be > 0 m, got {values}")
        return values

    def direct_kinematics(self, lengths, guess_position=None, guess_rotation=None,
                          tol_m: float = 1e-10, max_iterations: int = 12,
                          jacobian_guess: np.ndarray | None = None) -> GoughDKMResult:
        """Pose from strut lengths by Newton-Raphson (MoM3 §6.3, DKM_GP).

        Warm start from ``guess_*`` (default: home pose, identity). The Jacobian is
        re-evaluated whenever an iteration gains less than three orders of magnitude
        (a chord step with a recent J_h is as good as a Newton step for the small
        motions between two control cycles; far from the guess this is plain Newton).
        Convergence: every strut residual below ``tol_m``. Divergence: the residual grows twice in a row
        or passes 10 x max(1 m, strut range). Branch: the plate must stay above the base
        plane with its normal pointing away from the base (no mirror assembly), and a
        solve that travelled (re-linearised or took more than two steps) must keep the
        sign of det(J_h^-1) at home (no other assembly mode).
        ``jacobian_guess`` may pass J_h near the guess, which a warm-starting caller
        keeps from the previous solve (``GoughDKMSolver``).
        """
        target = self._validate_lengths(lengths)
        p = self.home_position.tolist() if guess_position is None else finite_floats(
            guess_position, 3, "guess_position")
        rot = ([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] if guess_rotation is None
               else validate_rotation(guess_rotation, "guess_rotation"))
        jh = None
        if jacobian_guess is not None:
            jh = finite_array(jacobian_guess, "jacobian_guess", (6, 6)).tolist()
        return self._newton(target, p, rot, jh, tol_m, max_iterations)

    def _newton(self, target: list, p: list, rot: list, jh, tol_m: float,
                max_iterations: int) -> GoughDKMResult:
        """dkm_newton_kernel from (p, rot) (floats; ``rot`` row-major) and ``jh`` (J_h
        near the guess, 6 x 6, or None), then the branch checks of ``_finish``."""
        p_a, rot_a = np.array(p, dtype=float), np.array(rot, dtype=float)
        have = jh is not None
        jh_a = np.array(jh, dtype=float) if have else np.empty((6, 6))
        code, iterations, evaluations, residual, have = dkm_newton_kernel(
            self._legs_a, np.asarray(target, dtype=float), p_a, rot_a, jh_a, have, float(tol_m),
            int(max_iterations), self._divergence_limit)
        return self._result(code, p_a, rot_a, iterations, evaluations, residual, jh_a if have else None,
                            max_iterations)

    def _result(self, code, p, rot, iterations, evaluations, residual, jh, max_iterations) -> GoughDKMResult:
        """The GoughDKMResult of a kernel's solve (``p`` (3,), ``rot`` (9,) its last iterate)."""
        if code == DKM_CONVERGED:
            return self._finish(p[0], p[1], p[2], rot, iterations, evaluations, residual, jh)
        reason = {DKM_DIVERGED_LIMIT: f"diverged: residual {residual:.3g} m above the limit "
                                      f"{self._divergence_limit:.3g} m",
                  DKM_DIVERGED_GROWTH: "diverged: residual grew twice in a row",
                  DKM_SINGULAR: "singular configuration (J_h^-1 not invertible)"}.get(
            code, f"no convergence in {max_iterations} iterations (residual {residual:.3g} m)")
        return self._fail(iterations, evaluations, residual, reason)

    def _finish(self, px, py, pz, rot, iterations, evaluations, residual, jh) -> GoughDKMResult:
        if pz <= 0.0 or rot[8] <= 0.0:
            return self._fail(iterations, evaluations, residual,
                              "mirror assembly: the plate is below the base plane or flipped")
        if evaluations or iterations > 2:
            # the solve travelled: it must not have crossed into another assembly mode,
            # which would flip the sign of det(J_h^-1) (a path between modes crosses a
            # singularity). Short warm-started solves cannot, and skip this 10 us check.
            position, rotation = np.array([px, py, pz]), np.array(rot).reshape(3, 3)
            if np.linalg.det(self.inverse_jacobian(position, rotation)) * self._home_det_sign <= 0.0:
                return self._fail(iterations, evaluations, residual,
                                  "another assembly mode: det(J_h^-1) has the opposite sign to home")
        return GoughDKMResult(np.array([px, py, pz]), np.array(rot).reshape(3, 3), True, iterations,
                              evaluations, residual, "", jh)

    @staticmethod
    def _fail(iterations, evaluations, residual, reason) -> GoughDKMResult:
        return GoughDKMResult(np.full(3, np.nan), np.full((3, 3), np.nan), False,
                              iterations, evaluations, residual, reason)

    def direct_kinematics_batch(self, lengths, guess_positions, guess_rotations,
                                tol_m: float = 1e-10, max_iterations: int = 12, chunk: int = 16384):
        """Vectorized DKM for (N, 6) strut lengths, warm-started per row.

        The compiled iteration of :meth:`direct_kinematics` on every row
        (dkm_batch_kernel: chord steps, J_h re-evaluated when a step gains less than
        three orders of magnitude, divergence, mirror and assembly-mode checks).
        Returns (positions (N, 3), rotations (N, 3, 3), converged (N,), iterations
        (N,)); rows that failed are NaN. (``chunk``: unused, kept for callers.)
        """
        lengths = finite_array(lengths, "strut lengths", (-1, 6))
        n = lengths.shape[0]
        guess_positions = finite_array(guess_positions, "guess_positions", (n, 3))
        guess_rotations = finite_array(guess_rotations, "guess_rotations", (n, 3, 3))
        distortion = np.abs(np.einsum("nji,njk->nik", guess_rotations, guess_rotations) - np.eye(3)).max(axis=(1, 2))
        bad = (distortion > 1e-6) | (np.linalg.det(guess_rotations) <= 0.0)
        if bad.any():
            raise ValueError(f"guess_rotations[{int(np.argmax(bad))}]: not a rotation matrix "
                             "(R^T R != I or det(R) <= 0)")
        p_out, r_out = np.empty((n, 3)), np.empty((n, 9))
        iters, ok = np.empty(n, dtype=np.int64), np.empty(n, dtype=bool)
        dkm_batch_kernel(self._legs_a, np.ascontiguousarray(lengths), np.ascontiguousarray(guess_positions),
                         np.ascontiguousarray(guess_rotations.reshape(n, 9)), float(tol_m), int(max_iterations),
                         self._divergence_limit, self._home_det_sign, p_out, r_out, ok, iters)
        r_out = r_out.reshape(n, 3, 3)
        return p_out, r_out, ok, iters


class GoughDKMSolver:
    """Warm-started DKM for a stream of measurements (one per control cycle).

    Keeps the last two poses and J_h (the data part of the model/data split: the
    GoughPlatform itself stays immutable). Each solve starts from the constant-velocity
    extrapolation of the last two solutions, p = 2 p_k - p_(k-1), R = exp(w) R_k with w
    the rotation vector of R_k R_(k-1)^T (an exact rotation: extrapolating with the
    matrix product itself lets rounding errors leave SO(3) and grow, and strut lengths
    cannot see a non-rigid plate), so that one Newton step usually suffices. A failed solve is returned as such and
    the next one starts again from the last good pose.
    """

    def __init__(self, platform: GoughPlatform, tol_m: float = 1e-10, max_iterations: int = 12):
        self.platform = platform
        self.tol_m = tol_m
        self.max_iterations = max_iterations
        self.reset()

    def reset(self, position=None, rotation=None) -> None:
        self._p = np.array(self.platform.home_position if position is None
                           else finite_floats(position, 3, "position"), dtype=float)
        self._r = np.array(np.eye(3).ravel() if rotation is None else validate_rotation(rotation, "rotation"),
                           dtype=float)
        # the solution one solve earlier: none after a reset or a failure (_p/_r then a
        # guess, no velocity to extrapolate)
        self._p0, self._r0, self._has_previous = self._p.copy(), self._r.copy(), False
        self._jh, self._has_jh = np.empty((6, 6)), False

    @property
    def position(self) -> np.ndarray:
        """The last good plate position (m)."""
        return self._p.copy()

    @property
    def rotation(self) -> np.ndarray:
        """The last good plate rotation."""
        return self._r.reshape(3, 3).copy()

    def solve(self, lengths) -> GoughDKMResult:
        """One measurement: dkm_warm_step_kernel (guess and Newton, compiled), then the
        branch checks; the state moves on only when it converged."""
        platform = self.platform
        target = np.asarray(lengths, dtype=float)
        if target.shape != (6,):
            platform._validate_lengths(lengths)            # raises, naming what is wrong
        p, rot = np.empty(3), np.empty(9)
        code, iterations, evaluations, residual, have_jh = dkm_warm_step_kernel(
            platform._legs_a, target, self._p, self._r, self._p0, self._r0, self._has_previous, self._jh,
            self._has_jh, self.tol_m, self.max_iterations, platform._divergence_limit, p, rot)
        if code == DKM_BAD_LENGTHS:
            platform._validate_lengths(lengths)            # raises, naming what is wrong
        result = platform._result(code, p, rot, iterations, evaluations, residual,
                                  self._jh.copy() if have_jh else None, self.max_iterations)
        if result.converged:
            self._has_jh = have_jh
            # after a reset the guess is not a pose of the motion: no velocity to extrapolate
            self._p0, self._r0 = (self._p, self._r) if self._has_previous else (p, rot)
            self._p, self._r, self._has_previous = p, rot, True
        else:
            self._has_jh = self._has_previous = False
        return result
