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

The platform is six passive struts of the bar model (``GoughPlatform.bars``; strut
i is measurement i): every equation above is a kernel of ``bars``, written once for
all strut machines (the hexapods' too). This module adds the metrology's own: the
warm-started stream with its extrapolated guess, and the assembly-branch checks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import bars as B
from .errors import FieldError
from .jit import direct_call, kernel
from .rotations import first_improper_rotation_kernel
from .validation import finite_array, finite_floats


def validate_rotation(value, name: str) -> list[float]:
    """A rotation matrix as 9 row-major floats; refuses non-finite values, a wrong
    shape, and matrices that are not rotations (|R^T R - I| > 1e-6 or det <= 0): six
    strut lengths cannot see a non-rigid plate, so a distorted guess would survive."""
    rot = np.asarray(value, dtype=float)
    if rot.shape != (3, 3) or not np.isfinite(rot).all():
        raise FieldError(name, f"expected a finite 3 x 3 rotation matrix, got {value!r}")
    if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) <= 0.0:
        raise FieldError(name, f"not a rotation matrix (R^T R != I or det(R) <= 0): {rot.tolist()}")
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
    jacobian: np.ndarray | None = None   # J_h of the last linearisation, (6, 6), to warm-start a next
                                         # direct_kinematics (GoughDKMSolver keeps its own: None there)


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


# dkm_warm_step_kernel: the readings are not lengths (the FK_* codes of bars otherwise)
DKM_BAD_LENGTHS = 5
# a converged solve on the wrong branch (plate_branch_code): the plate mirrored below the
# base plane or flipped; or in another assembly mode (det(J_h^-1) of the other sign)
DKM_MIRROR, DKM_OTHER_MODE = 6, 7


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:], float64[:], boolean, float64[:, :], boolean, "
        "float64[:, :], float64, int64, float64, float64[:], float64[:])")
def dkm_warm_step_kernel(bars, target, p1, r1, p0, r0, has_previous, jh, have_jh, rows, tol_m, max_iterations,
                         divergence_limit, p, rot):
    """One solve of a warm-starting solver (GoughDKMSolver.solve), compiled: the guess
    extrapolated from the last two solutions (p1, R1) and (p0, R0) when
    ``has_previous`` (``bars.extrapolated_pose_into``), else (p1, R1); then ``bars.chord_forward_kinematics_kernel``
    into ``p`` and ``rot``. DKM_BAD_LENGTHS (nothing solved) when a length is not
    finite and > 0."""
    for i in range(6):
        if not (0.0 < target[i] < math.inf):
            return DKM_BAD_LENGTHS, 0, 0, math.inf, have_jh
    if has_previous:
        B.extrapolated_pose_into(p1, r1, p0, r0, p, rot)
    else:
        p[:] = p1
        rot[:] = r1
    return B.chord_forward_kinematics_kernel(bars, target, p, rot, jh, have_jh, rows, False, tol_m, max_iterations,
                                             divergence_limit)


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:, :], boolean, int64, int64, float64)")
def plate_branch_code(bars, lengths, p, rot, rows, rows_valid, evaluations, iterations, home_det_sign):
    """The branch checks of a converged solve of the strut ``lengths`` at the plate's
    pose ``p``, ``rot`` (9, row-major); ``rows``: the unit pose Jacobian J_h^-1 there
    when ``rows_valid`` (else made here when the check needs it; overwritten):
    DKM_MIRROR unless the plate is above the base plane and not flipped; for a solve
    that travelled (re-linearised, or more than two steps) DKM_OTHER_MODE unless
    det(J_h^-1) has the sign it has at home (a path between assembly modes crosses a
    singularity: short warm-started solves cannot, and skip this check); else
    FK_CONVERGED."""
    if not (p[2] > 0.0 and rot[8] > 0.0):
        return DKM_MIRROR
    if evaluations > 0 or iterations > 2:
        if not rows_valid:
            B.unit_pose_jacobian_into(bars, p[0], p[1], p[2], (rot[0], rot[1], rot[2], rot[3], rot[4], rot[5],
                                                               rot[6], rot[7], rot[8]), lengths, rows)
        if not B.determinant6(rows) * home_det_sign > 0.0:
            return DKM_OTHER_MODE
    return B.FK_CONVERGED


@kernel("(float64[:, :], float64[:, :], float64[:, :], float64[:, :], float64, int64, float64, float64, "
        "float64[:, :], float64[:, :], boolean[:], int64[:])")
def dkm_batch_kernel(bars, lengths, guess_p, guess_r, tol_m, max_iterations, divergence_limit, home_det_sign,
                     p_out, r_out, ok, iterations):
    """``bars.chord_forward_kinematics_kernel`` on every row of ``lengths`` (N, 6) from its guess (``guess_r``
    rows row-major), with the branch checks (``plate_branch_code``). Rows that failed
    are NaN."""
    jh, rows = np.empty((6, 6)), np.empty((6, 6))
    for n in range(lengths.shape[0]):
        p, rot = p_out[n], r_out[n]
        p[:] = guess_p[n]
        rot[:] = guess_r[n]
        code, its, evaluations, _, _ = B.chord_forward_kinematics_kernel(bars, lengths[n], p, rot, jh, False, rows,
                                                                         True, tol_m, max_iterations, divergence_limit)
        good = code == B.FK_CONVERGED and plate_branch_code(bars, lengths[n], p, rot, rows, True, evaluations, its,
                                                             home_det_sign) == B.FK_CONVERGED
        ok[n] = good
        iterations[n] = its
        if not good:
            p[:] = math.nan
            rot[:] = math.nan


# GoughDKMSolver's state, one array: a warm state (bars.WARM_*: the last good pose
# (p1, R1), the one before (p0, R0)), then J_h of the last linearisation, then the
# solve's scratch for the unit pose Jacobian J_h^-1; flags: (has_previous, have_jh)
_P1, _R1, _P0, _R0, _JH = B.WARM_P1, B.WARM_R1, B.WARM_P0, B.WARM_R0, B.WARM_STATE_SIZE
_ROWS = _JH + 36
STATE_SIZE = _ROWS + 36


@kernel("(float64[:, :], float64[:], float64[::1], int64[:], float64, int64, float64, float64, float64[::1], "
        "float64[:, ::1])")
def dkm_solve_kernel(bars, target, state, flags, tol_m, max_iterations, divergence_limit, home_det_sign, p,
                     rotation):
    """One solve of ``GoughDKMSolver``, compiled whole: ``dkm_warm_step_kernel`` (the
    extrapolated guess, the chord iteration) from ``state``, the branch checks
    (``plate_branch_code``: DKM_MIRROR, DKM_OTHER_MODE), then the state moves on only
    after a good solve (p0, R0 <- p1, R1, or the solution itself after a reset; p1, R1
    <- the solution), and is reset to "no previous solution" after a failure. The last
    iterate into ``p`` (3,) and ``rotation`` (3, 3). Returns (code, iterations, J_h
    evaluations, residual)."""
    p1, r1, p0, r0 = state[_P1:_R1], state[_R1:_P0], state[_P0:_R0], state[_R0:_JH]
    jh = state[_JH:_ROWS].reshape((6, 6))
    rows = state[_ROWS:STATE_SIZE].reshape((6, 6))
    rot = rotation.reshape(9)
    has_previous = flags[0] != 0
    code, iterations, evaluations, residual, have = dkm_warm_step_kernel(
        bars, target, p1, r1, p0, r0, has_previous, jh, flags[1] != 0, rows, tol_m, max_iterations, divergence_limit,
        p, rot)
    if code == B.FK_CONVERGED:
        code = plate_branch_code(bars, target, p, rot, rows, False, evaluations, iterations, home_det_sign)
    if code == B.FK_CONVERGED:
        flags[1] = 1 if have else 0
        B.advance_warm_state(state, p, rot, has_previous)
        flags[0] = 1
    else:
        flags[0] = flags[1] = 0
    return code, iterations, evaluations, residual


@kernel("(float64[:, :], float64[:, :], float64[::1], int64[:], float64, int64, float64, float64, float64[:, :], "
        "int64[:], int64[:])")
def dkm_stream_kernel(bars, lengths, state, flags, tol_m, max_iterations, divergence_limit, home_det_sign, poses,
                      codes, iterations):
    """``dkm_solve_kernel`` over a stream of readings (N, 6) in one compiled loop, bit
    for bit N calls of it: into ``poses`` (N, 12: p, R row-major; NaN where it
    failed), ``codes`` (FK_*; FK_SINGULAR also for a wrong branch, DKM_BAD_LENGTHS) and
    ``iterations``."""
    p, rotation = np.empty(3), np.empty((3, 3))
    rot = rotation.reshape(9)
    for k in range(lengths.shape[0]):
        code, its, _, _ = dkm_solve_kernel(bars, lengths[k], state, flags, tol_m, max_iterations, divergence_limit,
                                           home_det_sign, p, rotation)
        iterations[k] = its
        codes[k] = B.FK_SINGULAR if code == DKM_MIRROR or code == DKM_OTHER_MODE else code
        if code == B.FK_CONVERGED:
            poses[k, 0:3] = p
            poses[k, 3:12] = rot
        else:
            poses[k, :] = math.nan


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
            raise FieldError("home_position", "the plate must be above the base plane (z > 0), "
                                              f"got z = {self.home_position[2]}")
        self._lo, self._hi = float(self.strut_limits[0]), float(self.strut_limits[1])
        self._divergence_limit = 10.0 * max(1.0, self._hi - self._lo if math.isfinite(self._hi) else 1.0)
        # the six passive struts as a bar model (``bars``): strut i is measurement i
        self.bars = B.bar_rows(self.base_points, self.plate_points, actuator=np.arange(6), kind=B.STRUT)
        self._home_det_sign = math.copysign(
            1.0, float(np.linalg.det(self.inverse_jacobian(self.home_position, np.eye(3)))))

    # ------------------------------------------------------------ inverse model
    def strut_lengths(self, position, rotation) -> np.ndarray:
        """l_i = |p + R b_i - A_i| (m); ``bars.strut_lengths_kernel``."""
        p, r = np.asarray(position, dtype=float), np.asarray(rotation, dtype=float)
        return B.strut_lengths_kernel(self.bars, p[0], p[1], p[2], *r.ravel().tolist())

    def strut_lengths_batch(self, positions, rotations) -> np.ndarray:
        """Strut lengths for (N, 3) positions and (N, 3, 3) rotations: (N, 6)."""
        positions, rotations = self._pose_rows(positions, rotations)
        out = np.empty((positions.shape[0], 6))
        B.strut_lengths_batch_kernel(self.bars, positions, rotations, out)
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
        (``bars.pose_from_lengths_jacobian_kernel``): ~3 us against ~20 us with numpy.
        Raises numpy.linalg.LinAlgError at a singular pose."""
        return B.pose_from_lengths_jacobian_kernel(self.bars, p[0], p[1], p[2], *r).tolist()

    def inverse_jacobian_batch(self, positions, rotations) -> np.ndarray:
        """J_h^-1 for N poses: (N, 6, 6); ``bars.unit_pose_jacobian_batch_kernel``."""
        positions, rotations = self._pose_rows(positions, rotations)
        out = np.empty((positions.shape[0], 6, 6))
        B.unit_pose_jacobian_batch_kernel(self.bars, positions, rotations, out)
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
        """``bars.chord_forward_kinematics_kernel`` from (p, rot) (floats; ``rot`` row-major) and ``jh`` (J_h
        near the guess, 6 x 6, or None), then the branch checks of ``_finish``."""
        p_a, rot_a = np.array(p, dtype=float), np.array(rot, dtype=float)
        have = jh is not None
        jh_a = np.array(jh, dtype=float) if have else np.empty((6, 6))
        rows = np.empty((6, 6))
        target_a = np.asarray(target, dtype=float)
        code, iterations, evaluations, residual, have = B.chord_forward_kinematics_kernel(
            self.bars, target_a, p_a, rot_a, jh_a, have, rows, True, float(tol_m), int(max_iterations),
            self._divergence_limit)
        if code == B.FK_CONVERGED:
            code = plate_branch_code(self.bars, target_a, p_a, rot_a, rows, True, evaluations, iterations,
                                     self._home_det_sign)
        return self._result(code, p_a, rot_a, iterations, evaluations, residual, jh_a if have else None,
                            max_iterations)

    def _result(self, code, p, rot, iterations, evaluations, residual, jh, max_iterations) -> GoughDKMResult:
        """The GoughDKMResult of a kernel's solve whose branch the caller has checked
        (``plate_branch_code``: FK_CONVERGED is a good solve); ``p`` (3,), ``rot`` (9,)
        its last iterate (the result holds copies of them)."""
        if code == B.FK_CONVERGED:
            return GoughDKMResult(p.copy(), rot.reshape(3, 3).copy(), True, iterations, evaluations, residual, "",
                                  jh)
        reason = {B.FK_DIVERGED: f"diverged: residual {residual:.3g} m above the limit "
                                      f"{self._divergence_limit:.3g} m",
                  B.FK_STALLED: "diverged: residual grew twice in a row",
                  B.FK_SINGULAR: "singular configuration (J_h^-1 not invertible)",
                  DKM_MIRROR: "mirror assembly: the plate is below the base plane or flipped",
                  DKM_OTHER_MODE: "another assembly mode: det(J_h^-1) has the opposite sign to home"}.get(
            code, f"no convergence in {max_iterations} iterations (residual {residual:.3g} m)")
        return self._fail(iterations, evaluations, residual, reason)

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
        guess_rotations = np.ascontiguousarray(guess_rotations.reshape(n, 9))
        bad = first_improper_rotation_kernel(guess_rotations, 1e-6)
        if bad >= 0:
            raise ValueError(f"guess_rotations[{bad}]: not a rotation matrix (R^T R != I or det(R) <= 0)")
        p_out, r_out = np.empty((n, 3)), np.empty((n, 9))
        iters, ok = np.empty(n, dtype=np.int64), np.empty(n, dtype=bool)
        dkm_batch_kernel(self.bars, np.ascontiguousarray(lengths), np.ascontiguousarray(guess_positions),
                         guess_rotations, float(tol_m), int(max_iterations), self._divergence_limit,
                         self._home_det_sign, p_out, r_out, ok, iters)
        r_out = r_out.reshape(n, 3, 3)
        return p_out, r_out, ok, iters


# GoughDKMSolver.solve makes every argument itself, with the declared types
_solve = direct_call(dkm_solve_kernel)
_FLOAT64 = np.dtype(np.float64)


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
        p = self.platform.home_position if position is None else finite_floats(position, 3, "position")
        r = np.eye(3).ravel() if rotation is None else validate_rotation(rotation, "rotation")
        # the solution one solve earlier: none after a reset or a failure (p1, R1 then a
        # guess, no velocity to extrapolate)
        self._state = np.zeros(STATE_SIZE)
        self._state[_P1:_R1] = self._state[_P0:_R0] = p
        self._state[_R1:_P0] = self._state[_R0:_JH] = np.asarray(r, dtype=float).ravel()
        self._flags = np.zeros(2, dtype=np.int64)

    @property
    def position(self) -> np.ndarray:
        """The last good plate position (m)."""
        return self._state[_P1:_R1].copy()

    @property
    def rotation(self) -> np.ndarray:
        """The last good plate rotation."""
        return self._state[_R1:_P0].reshape(3, 3).copy()

    def solve_stream(self, lengths) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`solve` over readings (N, 6) in one compiled loop (``dkm_stream_kernel``):
        (positions (N, 3), rotations (N, 3, 3), converged (N,), iterations (N,)), NaN
        where a reading failed; the state moves on as after N calls of :meth:`solve`."""
        lengths = np.ascontiguousarray(finite_array(lengths, "strut lengths", (-1, 6)))
        n = lengths.shape[0]
        poses, codes, iterations = np.empty((n, 12)), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
        platform = self.platform
        dkm_stream_kernel(platform.bars, lengths, self._state, self._flags, self.tol_m, self.max_iterations,
                          platform._divergence_limit, platform._home_det_sign, poses, codes, iterations)
        return poses[:, :3].copy(), poses[:, 3:].reshape(n, 3, 3).copy(), codes == B.FK_CONVERGED, iterations

    def solve(self, lengths) -> GoughDKMResult:
        """One measurement (``dkm_solve_kernel``: guess, Newton, branch checks, the
        state moving on only when it converged, compiled in one call)."""
        platform = self.platform
        target = lengths
        if type(target) is not np.ndarray or target.dtype is not _FLOAT64 or target.shape != (6,):
            target = np.asarray(lengths, dtype=float)
            if target.shape != (6,):
                platform._validate_lengths(lengths)        # raises, naming what is wrong
        p, rotation = np.empty(3), np.empty((3, 3))
        code, iterations, evaluations, residual = _solve(platform.bars, target, self._state, self._flags, self.tol_m,
                                                         self.max_iterations, platform._divergence_limit,
                                                         platform._home_det_sign, p, rotation)
        if code == B.FK_CONVERGED:
            return GoughDKMResult(p, rotation, True, iterations, evaluations, residual)
        if code == DKM_BAD_LENGTHS:
            platform._validate_lengths(lengths)            # raises, naming what is wrong
        return self.result_of(code, p, rotation, iterations, evaluations, residual)

    def kernel_arguments(self) -> tuple:
        """What ``dkm_solve_kernel`` takes besides the target and the outputs: (bars,
        state, flags, tol_m, max_iterations, divergence_limit, home_det_sign), for a
        compiled caller that solves inside its own kernel (the Gough sensor's reading).
        The state is this solver's: a solve there moves it on as :meth:`solve` does
        (taken anew for each call: :meth:`reset` replaces it)."""
        platform = self.platform
        return (platform.bars, self._state, self._flags, float(self.tol_m), int(self.max_iterations),
                platform._divergence_limit, platform._home_det_sign)

    def result_of(self, code: int, p, rotation, iterations: int, evaluations: int,
                  residual: float) -> GoughDKMResult:
        """The GoughDKMResult of a solve by ``dkm_solve_kernel`` (its code and last
        iterate ``p`` (3,), ``rotation`` (3, 3)), as :meth:`solve` returns it."""
        if code == B.FK_CONVERGED:
            return GoughDKMResult(p, rotation, True, iterations, evaluations, residual)
        return self.platform._result(code, p, np.asarray(rotation).ravel(), iterations, evaluations, residual,
                                     None, self.max_iterations)
