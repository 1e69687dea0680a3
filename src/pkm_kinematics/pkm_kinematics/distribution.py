"""Force distribution for redundantly actuated machines.

J is the n x m Jacobian J_m (qdot = J xdot, n drives > m DOF). Drive forces f
produce the platform wrench F = J^T f (Sliding Star eq. 5; ARCHI §4.4:
J_m^t f_d = f). With redundancy the solutions are f = J^T+ F + N z, N spanning
ker(J^T): the null-space part moves nothing and only loads the structure - the
internal force, what "drives fighting" is. Every distribution below returns forces
with J^T f = F checked (DistributionError otherwise).

* ``min_two_norm``   pseudo-inverse, z = 0 (ARCHI §4.4.1; Sliding Star eq. 9)
* ``min_inf_norm``   exact minimum of max|f_i| (ARCHI §4.4.2 minimises it by a
                     gradient step, whose switching Figure 18 shows); closed form for
                     a one-dimensional null space, linear programming otherwise
* ``min_p_norm``     the p-norm compromise suggested at the end of ARCHI §4.5
* ``two_arm``        zero internal force in the nacelle (ARCHI §4.3.1)
* ``two_arm_gravity`` the internal force M_n G sin(theta) of ARCHI §4.3.2
* ``project_forces`` n = J (J^T J)^-1 J^T n_d (Sliding Star eq. 6-8)
* ``add_prestress``  a chosen internal force along the null space

Why over 600 lines: every distribution of the papers (pseudo-inverse, infinity-norm,
p-norm, two-arm, prestress) with its compiled kernel and its check share the Gram
solves and the null-space directions written here once.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from .errors import DistributionError, FieldError
from .jit import kernel
from .planar import pair_force_map
from .validation import finite_floats

METHODS = ("pseudo_inverse", "inf_norm", "p_norm", "two_arm", "two_arm_gravity")
TWO_ARM = ("two_arm", "two_arm_gravity")       # need a planar machine of two leg pairs
# Above p ~ 64 the terms |f_i / max|f||^p underflow and the p-norm stops being
# computable in floating point; the infinity norm is the limit anyway.
P_NORM_MAX = 64.0
# a Gram matrix J^T J is singular when its determinant (or a pivot) falls below this part
# of the product of its diagonal (of its largest diagonal entry): the 3-DOF solves, the
# least squares of the dynamics, and the report's internal-force rows
GRAM_RTOL = 1e-13


def check_wrench(jac, forces, wrench, rtol: float = 1e-9) -> None:
    """Raise DistributionError unless J^T f reproduces the wrench, to ``rtol`` of the
    magnitude of the terms summed (sum_i |J_ik f_i|, the rounding-error scale).
    Compiled (:func:`check_wrench_kernel`): it runs every control cycle."""
    w = _floats(wrench)
    rows, f = rows_array(jac, len(w)), np.asarray(forces, dtype=float).ravel()
    if len(f) != rows.shape[0]:
        raise FieldError("forces", f"expected {rows.shape[0]} values (one per row of J), got {len(f)}")
    k, achieved = check_wrench_kernel(rows, f, np.array(w, dtype=float), rtol)
    if k >= 0:
        _raise_wrench_mismatch(k, achieved, w)


def _raise_wrench_mismatch(k: int, achieved: float, w) -> None:
    raise DistributionError(f"J^T f does not reproduce the wrench: component {k} is {achieved:.6g}, "
                            f"requested {w[k]:.6g} (wrench {list(w)})")


@kernel("(float64[:, :], float64[:], float64[:], float64)")
def check_wrench_kernel(rows, forces, wrench, rtol):
    """(k, achieved): the first wrench component k that J^T f misses, -1 if none."""
    for k in range(len(wrench)):
        wk = wrench[k]
        achieved = magnitude = 0.0
        for i in range(rows.shape[0]):
            term = rows[i, k] * forces[i]
            achieved += term
            magnitude += abs(term)
        if not abs(achieved - wk) <= rtol * max(1.0, magnitude, abs(wk)):
            return k, achieved
    return -1, 0.0


def _floats(values) -> list[float]:
    """Python floats of a short vector (iterating a numpy array yields slow scalars)."""
    return values.tolist() if isinstance(values, np.ndarray) else [float(v) for v in values]


def rows_array(rows, columns: int = 3) -> np.ndarray:
    """J given as rows of ``columns`` floats (or an array) as an (n, columns) float
    array for the kernels; ValueError for any other shape."""
    arr = rows if isinstance(rows, np.ndarray) and rows.dtype == np.float64 else np.array(rows, dtype=float)
    if arr.ndim == 2 and arr.shape[1] == columns:
        return arr
    if arr.size == 0:
        return arr.reshape(0, columns)
    raise FieldError("jac", f"expected n rows of {columns} values, got shape {arr.shape}")


@kernel("(float64[:, :],)")
def gram_rows(rows) -> tuple:
    """The 6 distinct entries (a00, a01, a02, a11, a12, a22) of J^T J for J an (n, 3)
    float array."""
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    for i in range(rows.shape[0]):
        j0, j1, j2 = rows[i, 0], rows[i, 1], rows[i, 2]
        a00 += j0 * j0
        a01 += j0 * j1
        a02 += j0 * j2
        a11 += j1 * j1
        a12 += j1 * j2
        a22 += j2 * j2
    return a00, a01, a02, a11, a12, a22


def gram_condition(rows) -> float:
    """2-norm condition number of J (n x 3, rows of 3 floats or an array) from the
    eigenvalues of J^T J (closed form for a symmetric 3 x 3 matrix); inf when
    singular. Compiled: ~1 us against ~20 us for ``np.linalg.cond``."""
    return gram_condition_kernel(rows_array(rows))


@kernel("(float64[:, :],)")
def gram_condition_kernel(rows):
    a00, a01, a02, a11, a12, a22 = gram_rows(rows)
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    tr = (a00 + a11 + a22) / 3.0
    p2 = (a00 - tr) ** 2 + (a11 - tr) ** 2 + (a22 - tr) ** 2 + 2.0 * p1
    p = math.sqrt(p2 / 6.0)
    if p <= 1e-300:
        return 1.0                                   # a multiple of the identity
    b00, b11, b22 = (a00 - tr) / p, (a11 - tr) / p, (a22 - tr) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    phi = math.acos(max(-1.0, min(1.0, r))) / 3.0
    lmax = tr + 2.0 * p * math.cos(phi)
    lmin = tr + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    if not lmin > 1e-14 * lmax:
        return math.inf
    return math.sqrt(lmax / lmin)


@kernel()
def _gram_solve_kernel(rows, b0, b1, b2):
    """Solve (J^T J) y = b (closed-form symmetric 3x3 inverse): (y0, y1, y2, solvable)."""
    a00, a01, a02, a11, a12, a22 = gram_rows(rows)
    c00 = a11 * a22 - a12 * a12
    c01 = a12 * a02 - a01 * a22
    c02 = a01 * a12 - a11 * a02
    det = a00 * c00 + a01 * c01 + a02 * c02
    # relative singularity test: det of a Gram matrix against the product of its diagonal
    if not abs(det) > GRAM_RTOL * abs(a00 * a11 * a22):
        return 0.0, 0.0, 0.0, False
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    return ((c00 * b0 + c01 * b1 + c02 * b2) / det, (c01 * b0 + c11 * b1 + c12 * b2) / det,
            (c02 * b0 + c12 * b1 + c22 * b2) / det, True)


SINGULAR_GRAM = "singular configuration: J^T J is not invertible (rank < 3)"
SINGULAR_NULL = "singular configuration: ker(J^T) is more than one-dimensional"


@kernel("(float64[:, :], float64[:])")
def least_squares_kernel(rows, values):
    """y = (J^T J)^-1 J^T v, the least-squares solution of J y = v: (y0, y1, y2, solvable)."""
    b0 = b1 = b2 = 0.0
    for i in range(rows.shape[0]):
        b0 += rows[i, 0] * values[i]
        b1 += rows[i, 1] * values[i]
        b2 += rows[i, 2] * values[i]
    return _gram_solve_kernel(rows, b0, b1, b2)


@kernel("(float64[:, :], float64[:])")
def gram_solve_n_kernel(rows, b):
    """(y, solvable): (J^T J) y = b for J of any width m (the n x 6 J_m of a hexapod),
    by a Cholesky factorisation of the m x m Gram matrix; not solvable when a pivot
    falls below 1e-13 of the largest diagonal entry (the relative test of the 3-DOF
    closed form, ``_gram_solve_kernel``: J has rank < m)."""
    n, m = rows.shape
    gram = np.zeros((m, m))
    for i in range(n):
        for j in range(m):
            rj = rows[i, j]
            for k in range(j + 1):
                gram[j, k] += rj * rows[i, k]
    scale = 0.0
    for j in range(m):
        scale = max(scale, gram[j, j])
    low = np.zeros((m, m))
    y = np.zeros(m)
    for j in range(m):                         # G = L L^T
        d = gram[j, j]
        for k in range(j):
            d -= low[j, k] * low[j, k]
        if not d > GRAM_RTOL * scale:
            return y, False
        low[j, j] = math.sqrt(d)
        for i in range(j + 1, m):
            v = gram[i, j]
            for k in range(j):
                v -= low[i, k] * low[j, k]
            low[i, j] = v / low[j, j]
    z = np.zeros(m)
    for i in range(m):                         # L z = b, L^T y = z
        v = b[i]
        for k in range(i):
            v -= low[i, k] * z[k]
        z[i] = v / low[i, i]
    for i in range(m - 1, -1, -1):
        v = z[i]
        for k in range(i + 1, m):
            v -= low[k, i] * y[k]
        y[i] = v / low[i, i]
    return y, True


@kernel("(float64[:, :], float64[:])")
def least_squares_n_kernel(rows, values):
    """(y, solvable): y = (J^T J)^-1 J^T v for J of any width (``gram_solve_n_kernel``)."""
    b = np.zeros(rows.shape[1])
    for i in range(rows.shape[0]):
        for j in range(rows.shape[1]):
            b[j] += rows[i, j] * values[i]
    return gram_solve_n_kernel(rows, b)


def _rows_and_values(rows, values) -> tuple[np.ndarray, np.ndarray]:
    """(J as an (n, 3) array, v as n floats) for the kernels; ValueError naming a
    mismatch."""
    rows, v = rows_array(rows), np.asarray(values, dtype=float).ravel()
    if len(v) != rows.shape[0]:
        raise FieldError("values", f"expected {rows.shape[0]} (one per row of J), got {len(v)}")
    return rows, v


def least_squares_rows(rows, values) -> list[float]:
    """(J^T J)^-1 J^T v for J given as n rows of 3 floats (or an (n, 3) array)."""
    y0, y1, y2, ok = least_squares_kernel(*_rows_and_values(rows, values))
    if not ok:
        raise DistributionError(SINGULAR_GRAM)
    return [y0, y1, y2]


def _min_two_norm_rows(rows, wrench) -> list[float]:
    return _distribute_floats(rows, _floats(wrench), False, False)


@kernel("(float64[:, :], float64[:])")
def project_kernel(rows, forces):
    """(J (J^T J)^-1 J^T f, solvable)."""
    y0, y1, y2, ok = least_squares_kernel(rows, forces)
    return rows[:, 0] * y0 + rows[:, 1] * y1 + rows[:, 2] * y2, ok


@kernel("(float64[:, :], float64[:])")
def internal_force_kernel(rows, forces):
    """(f - J (J^T J)^-1 J^T f, solvable): the null-space part of the forces."""
    projected, ok = project_kernel(rows, forces)
    return forces - projected, ok


def project_rows(rows, forces) -> list[float]:
    """:func:`project_forces` on floats (J as n rows of 3, or an (n, 3) array):
    J (J^T J)^-1 J^T f, the least-norm forces producing the wrench of ``forces``
    (their null-space part removed)."""
    projected, ok = project_kernel(*_rows_and_values(rows, forces))
    if not ok:
        raise DistributionError(SINGULAR_GRAM)
    return projected.tolist()


def _validate(jac, wrench) -> tuple[np.ndarray, list[float]]:
    """J as an (n, m) float array with n >= m, and the wrench as m floats."""
    jac = np.asarray(jac, dtype=float)
    if jac.ndim != 2 or jac.shape[0] < jac.shape[1] or jac.shape[1] == 0:
        raise FieldError("jac", f"expected an n x m Jacobian with n >= m drives, got shape {jac.shape}")
    return jac, finite_floats(wrench, jac.shape[1], "wrench")


def min_two_norm(jac, wrench, check: bool = True) -> np.ndarray:
    """f = J (J^T J)^-1 F: the minimum 2-norm drive forces (ARCHI §4.4.1, pseudo-inverse;
    Sliding Star eq. 9). No internal force: f is orthogonal to ker(J^T)."""
    jac, wrench = _validate(jac, wrench)
    if jac.shape[1] == 3:
        return np.array(_distribute_floats(jac, wrench, False, check))
    jac = np.ascontiguousarray(jac)
    y, ok = gram_solve_n_kernel(jac, np.array(wrench))
    if not ok:
        raise DistributionError(f"singular configuration: J has rank < {jac.shape[1]}")
    forces = jac @ y
    if check:
        check_wrench(jac, forces, wrench)
    return forces


def project_forces(jac, desired_forces) -> np.ndarray:
    """n = J (J^T J)^-1 J^T n_d (Sliding Star eq. 8): the drive forces of least norm that
    produce the same platform wrench F_d = J^T n_d (eq. 6) as the decentralised
    controllers' forces n_d; their internal (fighting) part is removed."""
    jac = np.asarray(jac, dtype=float)
    return min_two_norm(jac, jac.T @ np.asarray(desired_forces, dtype=float))


def null_space(jac) -> np.ndarray:
    """Orthonormal basis of ker(J^T), shape (n, n - rank)."""
    jac = np.asarray(jac, dtype=float)
    u, s, _ = np.linalg.svd(jac, full_matrices=True)
    rank = int(np.sum(s > s[0] * 1e-12)) if s.size else 0
    return u[:, rank:]


def _null_direction_rows(rows) -> list[float]:
    """Unit null vector of J^T for J given as 4 rows of 3 floats (sign not fixed)."""
    if len(rows) != 4 or len(rows[0]) != 3:
        raise FieldError("jac", f"null_direction needs a 4 x 3 Jacobian, got {len(rows)} x {len(rows[0])}")
    out, ok = _null_direction_kernel(rows_array(rows))
    if not ok:
        raise DistributionError(SINGULAR_NULL)
    return out.tolist()


@kernel("(float64[:, :],)")
def _null_direction_kernel(rows):
    """(unit null vector of J^T for a 4 x 3 J, found): n_i = (-1)^i det(J without row i)."""
    a0, a1, a2 = rows[0, 0], rows[0, 1], rows[0, 2]
    b0, b1, b2 = rows[1, 0], rows[1, 1], rows[1, 2]
    c0, c1, c2 = rows[2, 0], rows[2, 1], rows[2, 2]
    d0, d1, d2 = rows[3, 0], rows[3, 1], rows[3, 2]
    # 2 x 2 minors of the last two columns, shared by the four 3 x 3 determinants
    ab, ac, ad = a1 * b2 - a2 * b1, a1 * c2 - a2 * c1, a1 * d2 - a2 * d1
    bc, bd, cd = b1 * c2 - b2 * c1, b1 * d2 - b2 * d1, c1 * d2 - c2 * d1
    out = np.empty(4)
    out[0] = b0 * cd - c0 * bd + d0 * bc            # +det(rows 1, 2, 3)
    out[1] = -(a0 * cd - c0 * ad + d0 * ac)         # -det(rows 0, 2, 3)
    out[2] = a0 * bd - b0 * ad + d0 * ab            # +det(rows 0, 1, 3)
    out[3] = -(a0 * bc - b0 * ac + c0 * ab)         # -det(rows 0, 1, 2)
    norm = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2] + out[3] * out[3])
    if norm == 0.0:
        return out, False
    return out / norm, True


def null_direction(jac, reference=None) -> np.ndarray:
    """Unit vector spanning ker(J^T) for a 4 x 3 Jacobian, in closed form.

    n_i = (-1)^i det(J without row i) (the generalised cross product of the columns),
    normalised; its sign follows ``reference`` (n . reference >= 0) so that a control
    loop can keep it continuous, else the largest component is made positive.
    """
    n = np.array(_null_direction_rows(np.asarray(jac, dtype=float)))
    if reference is not None:
        if float(n @ reference) < 0.0:
            n = -n
    elif n[np.argmax(np.abs(n))] < 0.0:
        n = -n
    return n


@kernel("(float64[:], float64[:])")
def _min_inf_norm_1d_kernel(f0, n):
    """:func:`min_inf_norm_1d` (see there) on float arrays."""
    scale = 0.0
    for v in n:
        scale = max(scale, abs(v))
    eps = 1e-12 * scale if scale > 0.0 else 1.0
    count = 0
    intercepts = np.empty(len(n))     # rising lines a + b t (b > 0)
    slopes = np.empty(len(n))
    floor = 0.0
    for k in range(len(n)):
        fi, ni = f0[k], n[k]
        if ni > eps:
            intercepts[count], slopes[count] = fi, ni
            count += 1
        elif ni < -eps:
            intercepts[count], slopes[count] = -fi, -ni
            count += 1
        elif abs(fi) > floor:
            floor = abs(fi)
    if count == 0:
        return f0.copy()
    # the falling line of leg j is -a_j - b_j t. The crossing of a leg's own two lines
    # (height 0) never beats the other pairs once two legs have slopes: if the optimum
    # is 0, all lines meet at one t and every pair finds it; with a single sloped leg
    # no pair remains and the floor branch below places t. The envelope is evaluated at
    # each crossing and the least kept: in exact arithmetic that is the highest
    # crossing, but two crossings' heights can tie in floating point while their t
    # differ (a leg of slope ~1e-9 against two nearly parallel ones), and the wrong
    # one leaves a peak above the optimum.
    best_h, best_t = math.inf, 0.0
    for i in range(count):
        ai, bi = intercepts[i], slopes[i]
        for j in range(count):
            if j != i:
                aj, bj = intercepts[j], slopes[j]
                tc = -(aj + ai) / (bi + bj)
                h = 0.0
                for k in range(count):
                    h = max(h, abs(intercepts[k] + slopes[k] * tc))
                if h < best_h:
                    best_h, best_t = h, tc
    if count == 1:
        best_h = -math.inf
    t = best_t
    if floor >= best_h:
        floor = max(floor, 0.0)
        lo, hi = -math.inf, math.inf
        for k in range(len(n)):
            fi, ni = f0[k], n[k]
            if abs(ni) > eps:
                a, b = (-floor - fi) / ni, (floor - fi) / ni
                if a > b:
                    a, b = b, a
                lo, hi = max(lo, a), min(hi, b)
        t = min(max(0.0, lo), hi)
    return f0 + t * n


def min_inf_norm_1d(f0, n) -> np.ndarray:
    """Exact argmin over t of max_i |f0_i + t n_i| (a one-dimensional null space).

    The 2n lines +-(f0_i + t n_i) have slopes +-|n_i|. By LP duality the minimum of
    their upper envelope is the highest crossing of a rising line (a_i = sgn(n_i) f0_i,
    slope |n_i|) with a falling one (a_j = -sgn(n_j) f0_j, slope -|n_j|), at
    t = (a_j - a_i) / (|n_i| + |n_j|), height (a_i |n_j| + a_j |n_i|) / (|n_i| + |n_j|);
    that crossing is the unique minimiser. Legs with n_i = 0 add a floor |f0_i|: if it
    dominates, the minimisers form an interval and we take the t closest to 0, i.e.
    the minimum 2-norm solution among the optimal ones (f0 is the pseudo-inverse one).
    The crossing is chosen by evaluating the envelope at each: O(n^3) float operations.
    """
    f0, n = np.array(f0, dtype=float).ravel(), np.array(n, dtype=float).ravel()
    if len(f0) != len(n):
        raise FieldError("n", f"expected {len(f0)} values (as many as f0), got {len(n)}")
    return _min_inf_norm_1d_kernel(f0, n)


def min_inf_norm(jac, wrench, check: bool = True) -> np.ndarray:
    """Drive forces of least peak magnitude max_i |f_i| with J^T f = F (exact).

    One-dimensional null space (four drives, three DOF): closed form of
    :func:`min_inf_norm_1d` around the pseudo-inverse solution, compiled (it
    runs every control cycle). Otherwise a linear program (scipy HiGHS): minimise s
    subject to J^T f = F, -s <= f_i <= s.
    """
    jac, wrench = _validate(jac, wrench)
    n_drives, dof = jac.shape
    if n_drives == dof:
        return min_two_norm(jac, wrench, check)
    if n_drives == 4 and dof == 3:
        return np.array(_distribute_floats(jac, wrench, True, check))
    forces = min_inf_norm_lp(jac, wrench)
    if check:
        check_wrench(jac, forces, wrench)
    return forces


def min_inf_norm_lp(jac, wrench) -> np.ndarray:
    """Minimum infinity-norm distribution by linear programming (general null space)."""
    from scipy.optimize import linprog

    jac = np.asarray(jac, dtype=float)
    n = jac.shape[0]
    cost = np.zeros(n + 1)
    cost[-1] = 1.0
    eye = np.eye(n)
    a_ub = np.block([[eye, -np.ones((n, 1))], [-eye, -np.ones((n, 1))]])
    a_eq = np.hstack([jac.T, np.zeros((jac.shape[1], 1))])
    res = linprog(cost, A_ub=a_ub, b_ub=np.zeros(2 * n), A_eq=a_eq, b_eq=np.asarray(wrench, float),
                  bounds=[(None, None)] * (n + 1), method="highs")
    if not res.success:
        raise DistributionError(f"infinity-norm LP failed: {res.message}")
    return res.x[:n]


def min_p_norm(jac, wrench, p: float = 4.0, check: bool = True, tol: float = 1e-12,
               max_iterations: int = 50) -> np.ndarray:
    """Drive forces minimising ||f||_p with J^T f = F (2 < p < inf: between the 2-norm
    and the infinity norm, ARCHI §4.5). Newton's method along the null space, started
    from the pseudo-inverse solution; scipy BFGS when the null space is multi-dimensional."""
    if not 2.0 <= p <= P_NORM_MAX:
        raise FieldError("p", f"must be in [2, {P_NORM_MAX:g}] (use inf_norm beyond), got {p}")
    jac, wrench = _validate(jac, wrench)
    f0 = min_two_norm(jac, wrench, check=False)
    basis = null_space(jac)
    if basis.shape[1] == 0 or p == 2.0:
        return f0
    scale = float(np.abs(f0).max()) or 1.0
    g0 = f0 / scale
    if basis.shape[1] == 1:
        # Newton on the convex phi(t) = sum |g0 + t n|^p, with backtracking: phi'' can
        # vanish where components of f cross zero (p < 4), so a full step may overshoot
        n = basis[:, 0]
        t = 0.0
        phi = float(np.sum(np.abs(g0) ** p))
        for _ in range(max_iterations):
            f = g0 + t * n
            a = np.abs(f)
            d1 = float(np.sum(a ** (p - 1.0) * np.sign(f) * n))
            d2 = (p - 1.0) * float(np.sum(a ** (p - 2.0) * n * n))
            step = d1 / d2 if d2 > 0.0 else math.copysign(1.0, d1)
            for _ in range(60):
                with np.errstate(over="ignore"):      # an overshooting trial step may overflow
                    trial = float(np.sum(np.abs(g0 + (t - step) * n) ** p))
                if trial <= phi:
                    break
                step *= 0.5
            else:
                break                                 # no descent left: t is the minimiser
            t -= step
            gain = phi - trial
            phi = trial
            if abs(step) < tol or gain <= 1e-15 * phi:   # the step or phi has stopped moving
                break
        else:
            raise DistributionError(f"p-norm distribution: no convergence in {max_iterations} iterations")
        forces = scale * (g0 + t * n)
    else:
        from scipy.optimize import minimize

        def objective(z):
            f = g0 + basis @ z
            a = np.abs(f)
            return float(np.sum(a**p)), p * basis.T @ (a ** (p - 1.0) * np.sign(f))

        res = minimize(objective, np.zeros(basis.shape[1]), jac=True, method="BFGS",
                       options={"gtol": 1e-12})
        forces = scale * (g0 + basis @ res.x)
    if check:
        check_wrench(jac, forces, wrench)
    return forces


def prestress_direction(jac, direction) -> np.ndarray:
    """The unit internal force nearest ``direction`` (n drive forces): its projection
    on ker(J^T), normalised. For a null space of any dimension (an n x 6 J of a
    redundant hexapod has n - 6): the user says which drives to preload against which.
    DistributionError when the null space is empty or ``direction`` is orthogonal to it."""
    jac = np.asarray(jac, dtype=float)
    d = np.asarray(finite_floats(direction, jac.shape[0], "direction"))
    basis = null_space(jac)
    if basis.shape[1] == 0:
        raise DistributionError(f"prestress: no internal force exists with {jac.shape[0]} drives for "
                                f"{jac.shape[1]} DOF (ker(J^T) is empty)")
    n = basis @ (basis.T @ d)
    norm = float(np.linalg.norm(n))
    if not norm > 1e-9 * max(float(np.linalg.norm(d)), 1e-300):
        raise DistributionError("prestress: direction has no internal part (it is orthogonal to ker(J^T))")
    return n / norm


def add_prestress(jac, forces, prestress_n: float, reference=None, direction=None) -> np.ndarray:
    """f + prestress * n: an internal force of ``prestress_n`` newtons that leaves the
    wrench unchanged (e.g. to preload joints against backlash). n is the unit vector of
    ker(J^T) of a 4 x 3 J (``reference`` fixes its sign, see null_direction), or, for a
    null space of any dimension, the one nearest ``direction`` (prestress_direction)."""
    if direction is not None:
        return np.asarray(forces, dtype=float) + prestress_n * prestress_direction(jac, direction)
    shape = np.shape(jac)
    if shape != (4, 3):
        raise FieldError("prestress", f"the {shape[0]} x {shape[1]} Jacobian's internal forces are not one line: "
                                      f"give direction (the {shape[0]} drive forces to preload along)")
    return np.asarray(forces, dtype=float) + prestress_n * null_direction(jac, reference)


def internal_force_rows(rows, forces) -> list[float]:
    """:func:`internal_force` on floats (J as rows of 3): f - J (J^T J)^-1 J^T f."""
    internal, ok = internal_force_kernel(*_rows_and_values(rows, forces))
    if not ok:
        raise DistributionError(SINGULAR_GRAM)
    return internal.tolist()


def internal_force(jac, forces) -> np.ndarray:
    """The null-space (internal, fighting) component of drive forces: f - J (J^T J)^-1 J^T f."""
    jac = np.asarray(jac, dtype=float)
    forces = np.asarray(forces, dtype=float)
    return forces - project_forces(jac, forces)


def two_arm(machine, pose, wrench, internal_force_n: float = 0.0, check: bool = True) -> np.ndarray:
    """ARCHI §4.3 "2-arm robot like" distribution for a machine of two leg pairs.

    Solve J_f [f1; f2] = [f_x, f_y, m_z, (f1 - f2) . n] with the internal force
    (f1 - f2) . n set to ``internal_force_n`` (0 without gravity, §4.3.1; M_n G sin(theta)
    with gravity, §4.3.2 - see :func:`two_arm_gravity_internal_force`), then
    f_d = (J_v^-1 J_q)^T [f1; f2].
    """
    force_map, jf = pair_force_map(machine, pose)
    rhs = np.array([wrench[0], wrench[1], wrench[2], internal_force_n], dtype=float)
    try:
        pts = np.linalg.solve(jf, rhs)
    except np.linalg.LinAlgError as exc:
        raise DistributionError("two-arm: J_f is singular") from exc
    forces = force_map @ pts
    if check:
        check_wrench(machine.jacobian(pose), forces, wrench)
    return forces


def two_arm_gravity_internal_force(nacelle_mass_kg: float, theta_rad: float, gravity=9.81) -> float:
    """(f1 - f2) . n = M_n G sin(theta), the supplementary condition of ARCHI §4.3.2.

    ``gravity``: G (m/s^2, along -y: the paper's vertical plane, y up), or the gravity
    vector (g_x, g_y) of the machine, for which the condition reads -M_n g . n with
    n = (cos theta, sin theta) (the same for g = (0, -G))."""
    if isinstance(gravity, (int, float)):
        gravity = (0.0, -float(gravity))
    return -nacelle_mass_kg * (gravity[0] * math.cos(theta_rad) + gravity[1] * math.sin(theta_rad))


def _distribute_floats(rows, wrench: list, inf_norm: bool, check: bool) -> list[float]:
    """The float paths of min_two_norm (J as n rows of 3) and min_inf_norm (4 rows):
    the pseudo-inverse solution, moved along ker(J^T) to the least peak for inf_norm.
    Compiled (:func:`distribute_kernel`)."""
    forces, code, k, achieved = distribute_kernel(rows_array(rows), wrench[0], wrench[1], wrench[2],
                                                   inf_norm, check)
    if code:
        raise_distribution_error(code, k, achieved, wrench)
    return forces.tolist()


class DistributionCode(IntEnum):
    """The outcome of :func:`distribute_kernel` (as Ruckig's Result)."""
    OK = 0
    SINGULAR_GRAM = 1          # J^T J singular
    NULL_SPACE_NOT_1D = 2      # inf_norm: ker(J^T) is not one-dimensional
    WRENCH_MISSED = 3          # J^T f does not give the wrench (component k, achieved)


DISTRIBUTION_CODES = {
    DistributionCode.OK: "distributed; J^T f gives the wrench",
    DistributionCode.SINGULAR_GRAM: SINGULAR_GRAM,
    DistributionCode.NULL_SPACE_NOT_1D: SINGULAR_NULL,
    DistributionCode.WRENCH_MISSED: "J^T f does not reproduce the wrench",
}
_OK_CODE = int(DistributionCode.OK)           # the kernels' constants (a compiled kernel reads a module's ints)
_SINGULAR_GRAM_CODE, _NULL_NOT_1D_CODE, _WRENCH_MISSED_CODE = (int(DistributionCode.SINGULAR_GRAM),
                                                              int(DistributionCode.NULL_SPACE_NOT_1D),
                                                              int(DistributionCode.WRENCH_MISSED))


def raise_distribution_error(code: int, k: int, achieved: float, wrench) -> None:
    """The DistributionError of a non-zero code of :func:`distribute_kernel`."""
    if code == DistributionCode.SINGULAR_GRAM:
        raise DistributionError(SINGULAR_GRAM)
    if code == DistributionCode.NULL_SPACE_NOT_1D:
        raise DistributionError(SINGULAR_NULL)
    _raise_wrench_mismatch(k, achieved, wrench)


@kernel("(float64[:, :], float64, float64, float64, boolean, boolean)")
def distribute_kernel(rows, w0, w1, w2, inf_norm, check):
    """(forces, code, k, achieved): f = J (J^T J)^-1 F (ARCHI §4.4.1), for inf_norm
    moved along ker(J^T) to the least peak (§4.4.2, :func:`min_inf_norm_1d`), then
    J^T f = F checked. code: a DistributionCode (WRENCH_MISSED: on component k, J^T f
    gave ``achieved``)."""
    y0, y1, y2, ok = _gram_solve_kernel(rows, w0, w1, w2)
    if not ok:
        return np.zeros(rows.shape[0]), _SINGULAR_GRAM_CODE, -1, 0.0
    forces = rows[:, 0] * y0 + rows[:, 1] * y1 + rows[:, 2] * y2
    if inf_norm:
        n, ok = _null_direction_kernel(rows)
        if not ok:
            return forces, _NULL_NOT_1D_CODE, -1, 0.0
        forces = _min_inf_norm_1d_kernel(forces, n)
    if check:
        k, achieved = check_wrench_kernel(rows, forces, np.array([w0, w1, w2]), 1e-9)
        if k >= 0:
            return forces, _WRENCH_MISSED_CODE, k, achieved
    return forces, _OK_CODE, -1, 0.0


def distribute(method: str, jac, wrench, *, machine=None, pose=None, p: float = 4.0,
               internal_force_n: float = 0.0, prestress_n: float = 0.0, reference=None,
               prestress_direction=None) -> np.ndarray:
    """Dispatch by name (``METHODS``); adds ``prestress_n`` along the null space if non-zero
    (along ``prestress_direction`` projected on it, for a null space of any dimension)."""
    if method == "pseudo_inverse":
        forces = min_two_norm(jac, wrench)
    elif method == "inf_norm":
        forces = min_inf_norm(jac, wrench)
    elif method == "p_norm":
        forces = min_p_norm(jac, wrench, p)
    elif method in TWO_ARM:       # two_arm_gravity: the caller gives M_n G sin(theta) (§4.3.2)
        if machine is None or pose is None:
            raise ValueError(f"{method}: needs machine= and pose=")
        forces = two_arm(machine, pose, wrench, internal_force_n)
    else:
        raise FieldError("distribution", f"must be one of {list(METHODS)}, got {method!r}")
    if prestress_n:
        forces = add_prestress(jac, forces, prestress_n, reference, prestress_direction)
    return forces
