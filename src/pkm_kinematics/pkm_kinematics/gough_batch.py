"""Batched Gough DKM in structure-of-arrays form (used by GoughPlatform.direct_kinematics_batch).

Every quantity is a contiguous 1-D array over the poses of a chunk, and every step is
written out element-wise: the 6 x 6 Newton systems are solved by block elimination
with 3 x 3 adjugate inverses (a Schur complement), the rotation update is Rodrigues'
formula. This does ~1,000 array operations per chunk where numpy's batched
``linalg.inv`` and (N, 3, 6) broadcasting cost ~1.5 us and ~0.5 us per pose here.

The iteration is the one of ``GoughPlatform._newton``: Newton-Raphson on the strut
equations, chord steps with J_h re-evaluated when a step gains less than three
orders of magnitude, divergence when the residual grows twice in a row or passes the
limit, the mirror branch refused.
A row whose block pivots are ill-conditioned is only slowed down, never accepted
wrongly: convergence is judged on the strut residuals themselves.
"""

from __future__ import annotations

import numpy as np


def _inv3(m, dets=None):
    """Inverse of 3 x 3 matrices given as nested lists of arrays (adjugate / det);
    the determinants are appended to ``dets`` when given."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = m
    c00 = a11 * a22 - a12 * a21
    c01 = a12 * a20 - a10 * a22
    c02 = a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if dets is not None:
        dets.append(det)
    inv_det = 1.0 / det
    return [[c00 * inv_det, (a02 * a21 - a01 * a22) * inv_det, (a01 * a12 - a02 * a11) * inv_det],
            [c01 * inv_det, (a00 * a22 - a02 * a20) * inv_det, (a02 * a10 - a00 * a12) * inv_det],
            [c02 * inv_det, (a01 * a20 - a00 * a21) * inv_det, (a00 * a11 - a01 * a10) * inv_det]]


def _mul3(x, y):
    return [[x[i][0] * y[0][j] + x[i][1] * y[1][j] + x[i][2] * y[2][j] for j in range(3)] for i in range(3)]


def _matvec3(x, v):
    return [x[i][0] * v[0] + x[i][1] * v[1] + x[i][2] * v[2] for i in range(3)]


def _factor(geometry, dets=None):
    """Block factors of J_h^-1 = [[A, B], [C, D]] (rows: struts 0-2 and 3-5, columns:
    translation and rotation), so that a solve costs ~70 array operations:
    x2 = S^-1 (r2 - N r1), x1 = A^-1 r1 - M x2, with M = A^-1 B, N = C A^-1, S = D - C M."""
    rows = [(ux, uy, uz, rby * uz - rbz * uy, rbz * ux - rbx * uz, rbx * uy - rby * ux)
            for ux, uy, uz, rbx, rby, rbz in geometry]
    a = [list(r[:3]) for r in rows[:3]]
    b = [list(r[3:]) for r in rows[:3]]
    c = [list(r[:3]) for r in rows[3:]]
    d = [list(r[3:]) for r in rows[3:]]
    a_inv = _inv3(a, dets)
    m = _mul3(a_inv, b)
    n = _mul3(c, a_inv)
    cm = _mul3(c, m)
    s_inv = _inv3([[d[i][j] - cm[i][j] for j in range(3)] for i in range(3)], dets)
    return a_inv, m, n, s_inv


def _solve(factors, r):
    a_inv, m, n, s_inv = factors
    r1, r2 = r[:3], r[3:]
    nr1 = _matvec3(n, r1)
    x2 = _matvec3(s_inv, [r2[i] - nr1[i] for i in range(3)])
    ar1 = _matvec3(a_inv, r1)
    mx2 = _matvec3(m, x2)
    return [ar1[i] - mx2[i] for i in range(3)] + x2


def _where_factors(mask, new, old):
    return tuple([[np.where(mask, nv, ov) for nv, ov in zip(nrow, orow)] for nrow, orow in zip(nm, om)]
                 for nm, om in zip(new, old))


def dkm_chunk(base, plate, lengths, positions, rotations, tol_m: float, max_iterations: int,
              divergence_limit: float, home_det_sign: float):
    """Solve one chunk. base, plate: (6, 3); lengths (m, 6); positions (m, 3);
    rotations (m, 3, 3). Returns (positions, rotations, converged, iterations).
    A converged row must keep the sign of det(J_h^-1) at home, det(A) det(S) of the
    block factors (no other assembly mode), and stay above the base (no mirror)."""
    m = lengths.shape[0]
    target = [np.ascontiguousarray(lengths[:, i]) for i in range(6)]
    p = [np.ascontiguousarray(positions[:, k]) for k in range(3)]
    r = [np.ascontiguousarray(rotations[:, i, j]) for i in range(3) for j in range(3)]
    done = np.zeros(m, dtype=bool)
    failed = lengths.min(axis=1) <= 0.0
    iterations = np.zeros(m, dtype=int)
    previous = np.full(m, np.inf)
    growth = np.zeros(m, dtype=int)
    factors = None
    struts = [(tuple(a), tuple(b)) for a, b in zip(np.asarray(base).tolist(), np.asarray(plate).tolist())]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for iteration in range(max_iterations + 1):
            res, geometry = [], []
            for ((ax, ay, az), (bx, by, bz)), li in zip(struts, target):
                # R b_i without the products by exactly-zero plate coordinates
                rb = [sum(r[3 * k + j] * bj for j, bj in enumerate((bx, by, bz)) if bj != 0.0)
                      for k in range(3)]
                lx, ly, lz = p[0] + rb[0] - ax, p[1] + rb[1] - ay, p[2] + rb[2] - az
                length = np.sqrt(lx * lx + ly * ly + lz * lz)
                res.append(li - length)
                geometry.append((lx / length, ly / length, lz / length, rb[0], rb[1], rb[2]))
            worst = np.abs(res[0])
            for ri in res[1:]:
                worst = np.maximum(worst, np.abs(ri))
            active = ~(done | failed)
            newly = active & (worst <= tol_m)
            done |= newly
            iterations[newly] = iteration
            # as the scalar solver: NaN, past the divergence limit, or grown twice in a row
            growth = np.where(worst > previous, growth + 1, 0)
            bad = active & ~newly & (~(worst <= divergence_limit) | (growth >= 2))
            if iteration == max_iterations:
                bad = active & ~newly
            failed |= bad
            iterations[bad] = iteration
            active = ~(done | failed)
            if not active.any():
                break
            relinearise = active & (worst > 1e-3 * previous)
            if factors is None:
                factors = _factor(geometry)
            elif relinearise.any():
                factors = _where_factors(relinearise, _factor(geometry), factors)
            previous = np.where(active, worst, previous)
            step = _solve(factors, res)
            step = [np.where(active, s, 0.0) for s in step]
            p = [p[k] + step[k] for k in range(3)]
            # R <- exp([w]x) R (Rodrigues, exact also for the small steps of a warm start)
            wx, wy, wz = step[3:]
            theta2 = wx * wx + wy * wy + wz * wz
            small = theta2 < 1e-12
            theta = np.sqrt(np.where(small, 1.0, theta2))
            a = np.where(small, 1.0 - theta2 / 6.0, np.sin(theta) / theta)
            b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(theta)) / (theta * theta))
            e = [[1.0 - b * (wy * wy + wz * wz), -a * wz + b * wx * wy, a * wy + b * wx * wz],
                 [a * wz + b * wx * wy, 1.0 - b * (wx * wx + wz * wz), -a * wx + b * wy * wz],
                 [-a * wy + b * wx * wz, a * wx + b * wy * wz, 1.0 - b * (wx * wx + wy * wy)]]
            rr = [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]]
            r = [v for row in _mul3(e, rr) for v in row]
        dets = []
        _factor(geometry, dets)          # det(J_h^-1) = det(A) det(S - C A^-1 B)
        same_mode = dets[0] * dets[1] * home_det_sign > 0.0
    ok = done & ~failed & (p[2] > 0.0) & (r[8] > 0.0) & same_mode
    out_p = np.stack(p, axis=1)
    out_r = np.stack(r, axis=1).reshape(m, 3, 3)
    return out_p, out_r, ok, iterations
