"""The general machine model's equations: a platform joined to the base by bars
(../shared/MACHINE_MODEL.md), each written once as a compiled kernel.

Bar k runs from a base joint A_k to a platform joint B_k:

- A_k = a_k + q_j u_k on a rail driven by actuator j (u_k a unit vector), or a_k fixed;
- B_k = p + R b_k, b_k in the platform frame;
- its length is fixed, L_k, or is actuator j itself (a strut: l_k = q_j).

A model is one float array, ``bars`` (n, BAR_COLUMNS), a row per bar:
a (3), u (3), b (3), L (NaN for a strut), the actuator index (-1: none), STRUT or
RAIL, and the assembly branch sigma (+-1) of a rail bar. A pose is p (3 floats) and
R as a row-major 9-tuple; twists are t = (v, w) with w in the base frame.

The kernels:

- ``bar_vector``: e_k = B_k - A_k (the closure of MoM3 eq. 1 for a strut), and R b_k;
- ``bar_length``: l_k (L_k, or q_j of a strut);
- ``unit_pose_jacobian_into``: the rows [e_k, (R b_k) x e_k] / |e_k| of the pose
  Jacobian of the bar lengths |e_k| (d|e_k|/dt = row . t + (A_k's own motion));
  for a strut they are MoM3 eq. 2's J_h^-1 rows, and genhexkins' InverseJacobian;
- ``actuator_of_bar`` / ``actuators_into``: per actuator, its first bar's closed
  form: a strut q = |B - a|; a rail q = u.w + sigma sqrt(L^2 - |w|^2 + (u.w)^2),
  w = B - a (ARCHI §3.1, Orthoglide §3.1); per pose, in task coordinates and batched;
- ``forward_kinematics_kernel``: Newton (as many bars as pose unknowns) or
  Gauss-Newton (more bars: least squares) on the length misfits
  r_k = |e_k| - l_k over (p, R), R <- exp([dw]x) R, warm-started; the misfit left at
  the solution is what shows inconsistent actuators (a frozen or slipping encoder,
  a model error);
- ``chord_forward_kinematics_kernel``: the same for six bars with chord steps (J_h
  kept across steps and solves, re-evaluated when a step gains less than three orders
  of magnitude): the Gough metrology's stream of small moves (MoM3 §6.3);
- ``pose_from_lengths_jacobian_into``: J_h = (J_h^-1)^-1 of six bars (MoM3 eq. 1);
- ``strut_lengths_into``: |B_k - A_k| of every bar, a strut machine's IK (IKM_GP);
- ``rail_row_terms`` / ``rail_velocity_terms_into``: one bar per actuator on rails,
  J_x t = J_q q' per bar (MACHINE_MODEL.md; ARCHI §3.2, §3.4; Orthoglide eq. 3-8):
  J_m's row [e, (R b) x e] / (e . u), q', J_m' t and the row's rate, on the twist
  components the platform moves in (``task_pose_twist``: vx vy vz translating, vx vy
  wz planar); per pose, in task coordinates and batched;
- ``three_rail_forward_kinematics_kernel``: a translating platform on three rails in
  closed form (the three spheres, Orthoglide §3.1).

The machine classes wrap them: ``struts.StrutMachine``, ``rails.RailMachine`` (its
forward kinematics by configuration: ``planar.PlanarLeastSquaresFK``,
``translational.ThreeSpheresFK``), ``parallelogram.ParallelogramMachine`` and the
Gough metrology (``gough.GoughPlatform``: six passive struts).

Why over 600 lines: it is the model of MACHINE_MODEL.md, one compiled kernel per
equation in the document's order, the batched and per-pose forms beside the formula
they wrap; the kernels call each other, and one file keeps the model readable as one.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from .jit import kernel
from .rotations import exp_so3_kernel, mul3_kernel

BAR_COLUMNS = 13
COL_A, COL_U, COL_B, COL_LENGTH, COL_ACTUATOR, COL_TYPE, COL_BRANCH = 0, 3, 6, 9, 10, 11, 12
RAIL, STRUT = 0.0, 1.0

# forward_kinematics_kernel's codes (struts.FKCode names them)
FK_CONVERGED, FK_NO_CONVERGENCE, FK_DIVERGED, FK_SINGULAR, FK_STALLED = range(5)


class IKCode(IntEnum):
    """inverse_kinematics_into's outcome (IK_* below: the ints the kernels read)."""
    OK = 0
    UNREACHABLE = 1         # a bar cannot reach its actuator's line (a negative discriminant)


IK_CODES = {IKCode.OK: "every actuator position found",
            IKCode.UNREACHABLE: "a bar cannot reach its actuator's line (the pose is out of reach)"}
IK_OK, IK_UNREACHABLE = int(IKCode.OK), int(IKCode.UNREACHABLE)


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
def determinant6(a) -> float:
    """det(a) of a 6 x 6 matrix by elimination with partial pivoting (``a`` is
    overwritten): the product of the pivots, its sign flipped per row exchange.
    Inline for the same reason as ``invert6_into``: numpy's det allocates and calls
    LAPACK, which costs more than this on a 6 x 6."""
    det = 1.0
    for col in range(6):
        pivot = col
        for row in range(col + 1, 6):
            if abs(a[row, col]) > abs(a[pivot, col]):
                pivot = row
        if a[pivot, col] == 0.0:
            return 0.0
        if pivot != col:
            det = -det
            for j in range(col, 6):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
        det *= a[col, col]
        inv_p = 1.0 / a[col, col]
        for row in range(col + 1, 6):
            f = a[row, col] * inv_p
            if f != 0.0:
                for j in range(col + 1, 6):
                    a[row, j] -= f * a[col, j]
    return det


def bar_rows(base, platform, actuator, kind, rail=None, length=None, branch=None) -> np.ndarray:
    """The ``bars`` array of a model from per-bar lists (one row per bar)."""
    base = np.asarray(base, dtype=float).reshape(-1, 3)
    n = base.shape[0]
    out = np.zeros((n, BAR_COLUMNS))
    out[:, COL_A:COL_A + 3] = base
    out[:, COL_U:COL_U + 3] = 0.0 if rail is None else np.asarray(rail, dtype=float).reshape(n, 3)
    out[:, COL_B:COL_B + 3] = np.asarray(platform, dtype=float).reshape(n, 3)
    out[:, COL_LENGTH] = np.nan if length is None else np.asarray(length, dtype=float)
    out[:, COL_ACTUATOR] = np.asarray(actuator, dtype=float)
    out[:, COL_TYPE] = np.asarray(kind, dtype=float)
    out[:, COL_BRANCH] = 1.0 if branch is None else np.asarray(branch, dtype=float)
    return out


@kernel()
def bar_vector(bars, k, px, py, pz, r, q):
    """e_k = B_k - A_k = p + R b_k - a_k - q_j u_k (no rail term for a strut or a
    fixed base joint) at the pose (p, R row-major 9-tuple) and actuators ``q``.
    Returns (e_x, e_y, e_z, (R b_k)_x, (R b_k)_y, (R b_k)_z)."""
    bx, by, bz = bars[k, COL_B], bars[k, COL_B + 1], bars[k, COL_B + 2]
    rbx = r[0] * bx + r[1] * by + r[2] * bz
    rby = r[3] * bx + r[4] * by + r[5] * bz
    rbz = r[6] * bx + r[7] * by + r[8] * bz
    ex, ey, ez = px + rbx - bars[k, COL_A], py + rby - bars[k, COL_A + 1], pz + rbz - bars[k, COL_A + 2]
    j = int(bars[k, COL_ACTUATOR])
    if j >= 0 and bars[k, COL_TYPE] == 0.0:            # on a rail: A_k = a_k + q_j u_k
        ex, ey, ez = ex - q[j] * bars[k, COL_U], ey - q[j] * bars[k, COL_U + 1], ez - q[j] * bars[k, COL_U + 2]
    return ex, ey, ez, rbx, rby, rbz


@kernel()
def bar_length(bars, k, q):
    """l_k: the bar's fixed length, or its actuator's value for a strut."""
    if bars[k, COL_TYPE] == 1.0:
        return q[int(bars[k, COL_ACTUATOR])]
    return bars[k, COL_LENGTH]


@kernel()
def unit_row(bars, k, px, py, pz, r, q):
    """|e_k|, the unit vector u_k = e_k / |e_k| and its moment (R b_k) x u_k: the row of
    bar k in the unit pose Jacobian (zeros when the bar has zero length)."""
    ex, ey, ez, rbx, rby, rbz = bar_vector(bars, k, px, py, pz, r, q)
    n = math.sqrt(ex * ex + ey * ey + ez * ez)
    if not n > 0.0:
        return n, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ux, uy, uz = ex / n, ey / n, ez / n
    return n, ux, uy, uz, rby * uz - rbz * uy, rbz * ux - rbx * uz, rbx * uy - rby * ux


@kernel()
def unit_pose_jacobian_into(bars, px, py, pz, r, q, out) -> bool:
    """Rows [e_k, (R b_k) x e_k] / |e_k| into ``out`` (n, 6): d|e_k|/dt for the
    platform twist, actuators held. False where a bar has zero length."""
    for k in range(bars.shape[0]):
        n, ux, uy, uz, mx, my, mz = unit_row(bars, k, px, py, pz, r, q)
        if not n > 0.0:
            return False
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4], out[k, 5] = ux, uy, uz, mx, my, mz
    return True


@kernel()
def pose_from_lengths_jacobian_into(bars, px, py, pz, r, q, out, rows) -> bool:
    """The inverse of the 6 x 6 unit pose Jacobian into ``out``: the platform's twist
    per unit rate of six bar lengths, t = J_h l' (MoM3 eq. 1, J_h = (J_h^-1)^-1 with
    J_h^-1 the rows of ``unit_pose_jacobian_into``, eq. 2-3, made in ``rows`` (6, 6),
    a scratch), by Gauss-Jordan (``invert6_into``). False where a bar has zero length
    or the rows are singular."""
    if not unit_pose_jacobian_into(bars, px, py, pz, r, q, rows):
        return False
    return invert6_into(rows, out)


@kernel("(float64[:, :], float64, float64, float64, float64, float64, float64, float64, float64, float64, "
        "float64, float64, float64)")
def pose_from_lengths_jacobian_kernel(bars, px, py, pz, r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """``pose_from_lengths_jacobian_into`` of six struts at the pose (p, R row-major)
    as a new array, by LAPACK; raises numpy.linalg.LinAlgError at a singular pose."""
    rows = np.empty((6, 6))
    unit_pose_jacobian_into(bars, px, py, pz, (r00, r01, r02, r10, r11, r12, r20, r21, r22), np.zeros(6), rows)
    return np.linalg.inv(rows)


@kernel()
def strut_lengths_into(bars, px, py, pz, r, q, out):
    """|B_k - A_k| of every bar into ``out`` at the pose (p, R) and actuators ``q``:
    a strut machine's inverse kinematics (MoM3 §5.2's IKM_GP, l_k = |p + R b_k - a_k|;
    ``q`` is not read there)."""
    for k in range(bars.shape[0]):
        ex, ey, ez, _, _, _ = bar_vector(bars, k, px, py, pz, r, q)
        out[k] = math.sqrt(ex * ex + ey * ey + ez * ez)


@kernel("(float64[:, :], float64, float64, float64, float64, float64, float64, float64, float64, float64, "
        "float64, float64, float64)")
def strut_lengths_kernel(bars, px, py, pz, r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """``strut_lengths_into`` at the pose (p, R row-major) as a new array: the
    per-reading form."""
    out = np.empty(bars.shape[0])
    strut_lengths_into(bars, px, py, pz, (r00, r01, r02, r10, r11, r12, r20, r21, r22), np.zeros(bars.shape[0]),
                       out)
    return out


@kernel("(float64[:, :], float64[:, :], float64[:, :], float64[:, :])")
def strut_lengths_batch_kernel(bars, positions, rotations, out):
    """``strut_lengths_into`` of N poses (``rotations`` rows row-major) into ``out`` (N, n)."""
    zero = np.zeros(bars.shape[0])
    for i in range(positions.shape[0]):
        r = (rotations[i, 0], rotations[i, 1], rotations[i, 2], rotations[i, 3], rotations[i, 4],
             rotations[i, 5], rotations[i, 6], rotations[i, 7], rotations[i, 8])
        strut_lengths_into(bars, positions[i, 0], positions[i, 1], positions[i, 2], r, zero, out[i])


@kernel("(float64[:, :], float64[:, :], float64[:, :], float64[:, :, :])")
def unit_pose_jacobian_batch_kernel(bars, positions, rotations, out):
    """``unit_pose_jacobian_into`` of N poses of a strut machine (``rotations`` rows
    row-major) into ``out`` (N, n, 6)."""
    zero = np.zeros(bars.shape[0])
    for i in range(positions.shape[0]):
        r = (rotations[i, 0], rotations[i, 1], rotations[i, 2], rotations[i, 3], rotations[i, 4],
             rotations[i, 5], rotations[i, 6], rotations[i, 7], rotations[i, 8])
        unit_pose_jacobian_into(bars, positions[i, 0], positions[i, 1], positions[i, 2], r, zero, out[i])


@kernel()
def unit_row_rate(bars, k, px, py, pz, r, q, v0, v1, v2, w0, w1, w2):
    """The time derivative of bar k's row [u, (R b) x u] along the twist (v, w), the
    actuators held: [u', (R b)' x u + R b x u'] with (R b)' = w x R b, e' = v + (R b)',
    u' = (e' - u (u . e')) / |e| (zeros when the bar has zero length)."""
    ex, ey, ez, rbx, rby, rbz = bar_vector(bars, k, px, py, pz, r, q)
    n = math.sqrt(ex * ex + ey * ey + ez * ez)
    if not n > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ux, uy, uz = ex / n, ey / n, ez / n
    rdx, rdy, rdz = w1 * rbz - w2 * rby, w2 * rbx - w0 * rbz, w0 * rby - w1 * rbx
    edx, edy, edz = v0 + rdx, v1 + rdy, v2 + rdz
    ue = ux * edx + uy * edy + uz * edz
    udx, udy, udz = (edx - ux * ue) / n, (edy - uy * ue) / n, (edz - uz * ue) / n
    return (udx, udy, udz, (rdy * uz - rdz * uy) + (rby * udz - rbz * udy),
            (rdz * ux - rdx * uz) + (rbz * udx - rbx * udz), (rdx * uy - rdy * ux) + (rbx * udy - rby * udx))


@kernel()
def unit_pose_jacobian_derivative_into(bars, px, py, pz, r, q, t, out) -> bool:
    """The rows' time derivatives (``unit_row_rate``) along the twist t into ``out``
    (n, 6). False where a bar has zero length."""
    for k in range(bars.shape[0]):
        if not unit_row(bars, k, px, py, pz, r, q)[0] > 0.0:
            return False
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4], out[k, 5] = unit_row_rate(
            bars, k, px, py, pz, r, q, t[0], t[1], t[2], t[3], t[4], t[5])
    return True


@kernel()
def actuator_of_bar(bars, k, px, py, pz, r, zero):
    """(disc, q_j): the value of bar k's actuator that closes the bar at the pose, in
    closed form (MACHINE_MODEL.md): a strut q = |B - a|; a rail, the sphere/line
    intersection q = u.w + sigma sqrt(disc), disc = L^2 - |w|^2 + (u.w)^2, w = B - a
    (ARCHI §3.1, Orthoglide §3.1); disc < 0 (q NaN) where the rail cannot reach the
    joint (a strut's disc is 0). ``zero``: actuator values of 0 (n,)."""
    # w = B_k - a_k: the bar vector with the actuator at zero
    wx, wy, wz, _, _, _ = bar_vector(bars, k, px, py, pz, r, zero)
    if bars[k, COL_TYPE] == 1.0:
        return 0.0, math.sqrt(wx * wx + wy * wy + wz * wz)
    uw = bars[k, COL_U] * wx + bars[k, COL_U + 1] * wy + bars[k, COL_U + 2] * wz
    # summed in this order so that a planar machine's (wz = 0) is bit for bit the
    # per-pose and batched planar IK's: at the edge of reach disc is exactly 0 there
    disc = bars[k, COL_LENGTH] * bars[k, COL_LENGTH] - wx * wx - wy * wy - wz * wz + uw * uw
    if not disc >= 0.0:
        return disc, math.nan
    return disc, uw + bars[k, COL_BRANCH] * math.sqrt(disc)


@kernel()
def actuators_into(bars, px, py, pz, r, q):
    """Actuator values of the pose (p, R row-major tuple) into ``q``: each actuator
    from the first bar it drives (``actuator_of_bar``). Returns (code, bar):
    IK_UNREACHABLE with the bar whose rail cannot reach its platform joint."""
    q[:] = math.nan                        # NaN: the actuator's first bar not met yet
    for k in range(bars.shape[0]):
        j = int(bars[k, COL_ACTUATOR])
        if j < 0 or not math.isnan(q[j]):
            continue
        q[j] = 0.0                         # bar k reads only its own actuator: w = B - a
        disc, q[j] = actuator_of_bar(bars, k, px, py, pz, r, q)
        if not disc >= 0.0:
            return IK_UNREACHABLE, k
    return IK_OK, -1


@kernel("(float64[:, :], float64[:], float64[:], float64[:])")
def inverse_kinematics_into(bars, p, rot, q):
    """``actuators_into`` at the pose (p (3,), R (9,) row-major arrays)."""
    return actuators_into(bars, p[0], p[1], p[2], (rot[0], rot[1], rot[2], rot[3], rot[4], rot[5], rot[6], rot[7],
                                                   rot[8]), q)


@kernel("(float64[:, :], float64[:, :], float64[:, :], float64[:, :], boolean[:])")
def inverse_kinematics_batch_kernel(bars, positions, rotations, q, reachable):
    """Every actuator of every pose (N; ``rotations`` rows row-major) from its first
    bar (``actuator_of_bar``) into ``q`` (N, m): NaN for an actuator whose bar cannot
    reach (the others are still solved), ``reachable`` False for its pose."""
    m = q.shape[1]
    done = np.empty(m, dtype=np.bool_)
    for i in range(positions.shape[0]):
        r = (rotations[i, 0], rotations[i, 1], rotations[i, 2], rotations[i, 3], rotations[i, 4],
             rotations[i, 5], rotations[i, 6], rotations[i, 7], rotations[i, 8])
        done[:] = False
        reachable[i] = True
        for k in range(bars.shape[0]):
            j = int(bars[k, COL_ACTUATOR])
            if j < 0 or done[j]:
                continue
            done[j] = True
            q[i, j] = 0.0                  # bar k reads only its own actuator: w = B - a
            disc, q[i, j] = actuator_of_bar(bars, k, positions[i, 0], positions[i, 1], positions[i, 2], r, q[i])
            if not disc >= 0.0:
                reachable[i] = False


class VelocityTermsCode(IntEnum):
    """rail_velocity_terms_kernel's outcome per bar (VT_* below: the kernels' ints)."""
    OK = 0
    UNREACHABLE = 1         # the bar cannot close at the pose: its row is NaN
    SINGULAR = 2            # s = e . u = 0 (a serial singularity): its row is infinite


VELOCITY_TERMS_CODES = {VelocityTermsCode.OK: "the bar's row, rate and bias",
                        VelocityTermsCode.UNREACHABLE: "the bar cannot close at the pose (row NaN)",
                        VelocityTermsCode.SINGULAR: "e . u = 0: a serial singularity of the bar (row infinite)"}
VT_OK, VT_UNREACHABLE, VT_SINGULAR = (int(VelocityTermsCode.OK), int(VelocityTermsCode.UNREACHABLE),
                                      int(VelocityTermsCode.SINGULAR))


@kernel()
def rail_row_terms(bars, k, px, py, pz, r, q, t, with_rate):
    """Bar k on a rail, its actuator j at q[j] (closed): (code, s, row, qdot, bias,
    row rate), MACHINE_MODEL.md's J_x t = J_q q' for one bar per actuator (ARCHI §3.2,
    §3.4; Orthoglide eq. 3-8): with e = B - A, g = [e, (R b) x e] and s = e . u, the
    J_m row g / s, q'_j = g . t / s, and along the twist t = (v, w), with
    (R b)' = w x R b and e' = v + (R b)' - q'_j u, g' = [e', (R b)' x e + (R b) x e'],
    the row's rate g' / s - g s' / s^2 (s' = e' . u) and the bias J_m' t of
    q'' = J_m t' + J_m' t. Rows and rates are 6-tuples (the rate only ``with_rate``,
    else the row again); code VT_SINGULAR (e perpendicular to the rail: s = 0, J_m
    unbounded)."""
    ex, ey, ez, rbx, rby, rbz = bar_vector(bars, k, px, py, pz, r, q)
    ux, uy, uz, length = bars[k, COL_U], bars[k, COL_U + 1], bars[k, COL_U + 2], bars[k, COL_LENGTH]
    sv = ex * ux + ey * uy + ez * uz
    g = (ex, ey, ez, rby * ez - rbz * ey, rbz * ex - rbx * ez, rbx * ey - rby * ex)
    if sv * sv <= 1e-18 * length * length:
        return VT_SINGULAR, sv, g, 0.0, 0.0, g
    gv = g[0] * t[0] + g[1] * t[1] + g[2] * t[2] + g[3] * t[3] + g[4] * t[4] + g[5] * t[5]
    qdot = gv / sv
    rdx, rdy, rdz = t[4] * rbz - t[5] * rby, t[5] * rbx - t[3] * rbz, t[3] * rby - t[4] * rbx
    edx, edy, edz = t[0] + rdx - qdot * ux, t[1] + rdy - qdot * uy, t[2] + rdz - qdot * uz
    # ((R b)' x e = (w x R b) x e = R b (w . e) - w (R b . e): summed in this form, a
    # planar machine's terms are bit for bit those of its own former kernel)
    we, be = t[3] * ex + t[4] * ey + t[5] * ez, rbx * ex + rby * ey + rbz * ez
    gd = (edx, edy, edz, (rby * edz - rbz * edy) + (rbx * we - t[3] * be),
          (rbz * edx - rbx * edz) + (rby * we - t[4] * be), (rbx * edy - rby * edx) + (rbz * we - t[5] * be))
    gdv = gd[0] * t[0] + gd[1] * t[1] + gd[2] * t[2] + gd[3] * t[3] + gd[4] * t[4] + gd[5] * t[5]
    sdot = edx * ux + edy * uy + edz * uz
    bias = gdv / sv - gv * sdot / (sv * sv)
    if not with_rate:
        return VT_OK, sv, g, qdot, bias, g
    inv, k2 = 1.0 / sv, sdot / (sv * sv)
    rate = (gd[0] * inv - g[0] * k2, gd[1] * inv - g[1] * k2, gd[2] * inv - g[2] * k2,
            gd[3] * inv - g[3] * k2, gd[4] * inv - g[4] * k2, gd[5] * inv - g[5] * k2)
    return VT_OK, sv, g, qdot, bias, rate


@kernel()
def task_pose_twist(columns, x0, x1, x2, v0, v1, v2):
    """The platform pose (p, R row-major) and twist t (6) of the task coordinates x
    and rates v of a machine whose platform moves in the twist components
    ``columns`` (three of vx vy vz wx wy wz: a translating platform's vx vy vz, a
    planar one's vx vy wz): a translation column's coordinate is that component of p,
    a rotation column's the angle about that base axis (at most one), the rates the
    twist's components."""
    p0 = p1 = p2 = t0 = t1 = t2 = t3 = t4 = t5 = 0.0          # floats: no allocation per cycle
    r = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    for i in range(3):
        c = columns[i]
        xi = x0 if i == 0 else (x1 if i == 1 else x2)
        vi = v0 if i == 0 else (v1 if i == 1 else v2)
        if c == 0:
            p0, t0 = xi, vi
        elif c == 1:
            p1, t1 = xi, vi
        elif c == 2:
            p2, t2 = xi, vi
        else:
            co, si = math.cos(xi), math.sin(xi)
            if c == 3:
                r, t3 = (1.0, 0.0, 0.0, 0.0, co, -si, 0.0, si, co), vi
            elif c == 4:
                r, t4 = (co, 0.0, si, 0.0, 1.0, 0.0, -si, 0.0, co), vi
            else:
                r, t5 = (co, -si, 0.0, si, co, 0.0, 0.0, 0.0, 1.0), vi
    return p0, p1, p2, r, (t0, t1, t2, t3, t4, t5)


@kernel()
def rail_velocity_terms_into(bars, px, py, pz, r, t, columns, q, rows, qdot, bias, rates):
    """The velocity terms of a machine with one bar per actuator on rails (ARCHI,
    Sliding Star, the Orthoglide, the Delta; MACHINE_MODEL.md): per actuator, its
    first bar closed (``actuator_of_bar``), its J_m row, q', J_m' t and the row's
    rate (``rail_row_terms``), the rows restricted to the task's twist ``columns``
    (vx, vy, vz for a translating platform; vx, vy, wz for a planar one). Into
    ``q``, ``rows`` (m, d), ``qdot``, ``bias`` and, unless it has no rows,
    ``rates`` (m, d). Returns (code, bar): VT_UNREACHABLE or VT_SINGULAR with the
    first bar that fails, in bar order."""
    q[:] = math.nan                        # NaN: the actuator's first bar not met yet
    for k in range(bars.shape[0]):
        j = int(bars[k, COL_ACTUATOR])
        if j < 0 or not math.isnan(q[j]):
            continue
        q[j] = 0.0                         # bar k reads only its own actuator: w = B - a
        disc, q[j] = actuator_of_bar(bars, k, px, py, pz, r, q)
        if not disc >= 0.0:
            return VT_UNREACHABLE, k
        code, sv, g, qdot[j], bias[j], rate = rail_row_terms(bars, k, px, py, pz, r, q, t, rates.shape[0] > 0)
        if code != VT_OK:
            return code, k
        for c in range(columns.shape[0]):
            rows[j, c] = g[columns[c]] / sv
        if rates.shape[0]:
            for c in range(columns.shape[0]):
                rates[j, c] = rate[columns[c]]
    return VT_OK, -1


_RAIL_POSE = "(float64[:, :], int64, float64, float64, float64, UniTuple(float64, 9), UniTuple(float64, 6), int64[:])"
_RAIL_TASK = "(float64[:, :], int64, int64[:], float64, float64, float64, float64, float64, float64)"


@kernel(_RAIL_POSE)
def rail_velocity_terms_kernel(bars, m, px, py, pz, r, t, columns):
    """``rail_velocity_terms_into`` at one pose, new arrays: (q (m,), J_m (m, d), q',
    J_m' t, code, bar); the per-cycle form (every array returned costs a few hundred
    ns: the rows' rates have their own kernel)."""
    d = columns.shape[0]
    q, rows, qdot, bias = np.empty(m), np.empty((m, d)), np.empty(m), np.empty(m)
    code, bar = rail_velocity_terms_into(bars, px, py, pz, r, t, columns, q, rows, qdot, bias, np.empty((0, d)))
    return q, rows, qdot, bias, code, bar


@kernel(_RAIL_POSE)
def rail_jacobian_derivative_kernel(bars, m, px, py, pz, r, t, columns):
    """J_m' (m, d) along the twist t (``rail_velocity_terms_into``'s rates): (J_m',
    code, bar)."""
    d = columns.shape[0]
    q, rows, qdot, bias, rates = np.empty(m), np.empty((m, d)), np.empty(m), np.empty(m), np.empty((m, d))
    code, bar = rail_velocity_terms_into(bars, px, py, pz, r, t, columns, q, rows, qdot, bias, rates)
    return rates, code, bar


@kernel(_RAIL_TASK)
def rail_task_velocity_terms_kernel(bars, m, columns, x0, x1, x2, v0, v1, v2):
    """``rail_velocity_terms_kernel`` (``m`` actuators) in task coordinates
    (``task_pose_twist``): the per-cycle form for a machine and its dynamic model."""
    px, py, pz, r, t = task_pose_twist(columns, x0, x1, x2, v0, v1, v2)
    return rail_velocity_terms_kernel(bars, m, px, py, pz, r, t, columns)


@kernel(_RAIL_TASK)
def rail_task_jacobian_derivative_kernel(bars, m, columns, x0, x1, x2, v0, v1, v2):
    """``rail_jacobian_derivative_kernel`` in task coordinates."""
    px, py, pz, r, t = task_pose_twist(columns, x0, x1, x2, v0, v1, v2)
    return rail_jacobian_derivative_kernel(bars, m, px, py, pz, r, t, columns)


@kernel("(float64[:, :], int64, int64[:], float64, float64, float64)")
def rail_task_inverse_kinematics_kernel(bars, m, columns, x0, x1, x2):
    """``inverse_kinematics_kernel`` in task coordinates (``task_pose_twist``):
    (q (m,), code, bar)."""
    px, py, pz, r, _ = task_pose_twist(columns, x0, x1, x2, 0.0, 0.0, 0.0)
    q = np.empty(m)
    code, bar = actuators_into(bars, px, py, pz, r, q)
    return q, code, bar


@kernel("(float64[:, :], float64[:, :], float64[:, :], int64[:], float64[:, :], float64[:, :, :], boolean[:])")
def rail_jacobian_batch_kernel(bars, positions, rotations, columns, q, rows, ok):
    """``rail_velocity_terms_into`` at N poses at rest (``rotations`` rows
    row-major): actuators ``q`` (N, m) and J_m ``rows`` (N, m, d); ``ok`` False and
    the rows NaN where a bar cannot close (q NaN too), inf at a serial singularity
    (a bar perpendicular to its rail: J_m unbounded)."""
    m, d = q.shape[1], columns.shape[0]
    qdot, bias, rates = np.empty(m), np.empty(m), np.empty((0, d))
    rest = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for i in range(positions.shape[0]):
        r = (rotations[i, 0], rotations[i, 1], rotations[i, 2], rotations[i, 3], rotations[i, 4],
             rotations[i, 5], rotations[i, 6], rotations[i, 7], rotations[i, 8])
        code, _ = rail_velocity_terms_into(bars, positions[i, 0], positions[i, 1], positions[i, 2], r, rest,
                                           columns, q[i], rows[i], qdot, bias, rates)
        ok[i] = code == VT_OK
        if code == VT_UNREACHABLE:
            rows[i] = math.nan
            q[i] = math.nan
        elif code == VT_SINGULAR:
            rows[i] = math.inf


class ThreeSpheresCode(IntEnum):
    """three_rail_forward_kinematics_kernel's outcome (TRI_* below: the kernels' ints)."""
    OK = 0
    COLLINEAR = 1           # the three sphere centres are collinear: no unique intersection
    NOT_MEETING = 2         # the three spheres do not meet (the strut lengths cannot close)
    OTHER_BRANCH = 3        # they meet, but a bar is on its other assembly branch (the bar named)


THREE_SPHERES_CODES = {ThreeSpheresCode.OK: "the platform point on the working-mode side",
                       ThreeSpheresCode.COLLINEAR: "the sphere centres are collinear (a singular configuration)",
                       ThreeSpheresCode.NOT_MEETING: "the three spheres do not meet (out of reach)",
                       ThreeSpheresCode.OTHER_BRANCH: "a bar on its other assembly branch (bar: which)"}
TRI_OK, TRI_COLLINEAR, TRI_NOT_MEETING, TRI_OTHER_BRANCH = (int(c) for c in ThreeSpheresCode)


@kernel("(float64[:, :], float64, float64, float64, float64)")
def three_rail_forward_kinematics_kernel(bars, q0, q1, q2, side):
    """The forward kinematics of a translating platform on three rail bars in closed
    form (Orthoglide §3.1; MoM3's Delta): p is where the three spheres of centres
    S_i = a_i + q_i u_i - b_i and radii L_i meet, on the working-mode ``side`` of the
    centres' plane (that side changes only through a parallel singularity, Orthoglide
    §3.3), each bar then checked on its assembly branch ((B_i - A_i) . u_i has the
    sign of -sigma_i). Returns (px, py, pz, code, bar): TRI_COLLINEAR (the centres
    on a line), TRI_NOT_MEETING, TRI_OTHER_BRANCH with the bar."""
    qs = (q0, q1, q2)
    s = np.empty((3, 3))
    for i in range(3):
        for k in range(3):
            s[i, k] = bars[i, COL_A + k] + qs[i] * bars[i, COL_U + k] - bars[i, COL_B + k]
    sq1, sq2, sq3 = (bars[0, COL_LENGTH] * bars[0, COL_LENGTH], bars[1, COL_LENGTH] * bars[1, COL_LENGTH],
                     bars[2, COL_LENGTH] * bars[2, COL_LENGTH])
    ux, uy, uz = s[1, 0] - s[0, 0], s[1, 1] - s[0, 1], s[1, 2] - s[0, 2]
    vx, vy, vz = s[2, 0] - s[0, 0], s[2, 1] - s[0, 1], s[2, 2] - s[0, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    n2 = nx * nx + ny * ny + nz * nz
    if not n2 > 1e-18 * (ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz):
        return 0.0, 0.0, 0.0, TRI_COLLINEAR, -1
    k2 = 0.5 * (sq1 - sq2 + ux * ux + uy * uy + uz * uz)
    k3 = 0.5 * (sq1 - sq3 + vx * vx + vy * vy + vz * vz)
    # foot of the intersection line: (k2 (v x n) + k3 (n x u)) / |n|^2
    fx = (k2 * (vy * nz - vz * ny) + k3 * (ny * uz - nz * uy)) / n2
    fy = (k2 * (vz * nx - vx * nz) + k3 * (nz * ux - nx * uz)) / n2
    fz = (k2 * (vx * ny - vy * nx) + k3 * (nx * uy - ny * ux)) / n2
    rest = sq1 - (fx * fx + fy * fy + fz * fz)
    if not rest >= 0.0:
        return 0.0, 0.0, 0.0, TRI_NOT_MEETING, -1
    h = side * math.sqrt(rest / n2)
    px, py, pz = s[0, 0] + fx + h * nx, s[0, 1] + fy + h * ny, s[0, 2] + fz + h * nz
    identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    q = np.array([q0, q1, q2])
    for i in range(3):
        ex, ey, ez, _, _, _ = bar_vector(bars, i, px, py, pz, identity, q)
        if (ex * bars[i, COL_U] + ey * bars[i, COL_U + 1] + ez * bars[i, COL_U + 2]) * bars[i, COL_BRANCH] > 0.0:
            return px, py, pz, TRI_OTHER_BRANCH, i
    return px, py, pz, TRI_OK, -1


@kernel("(float64[:, :], float64[:, :], float64, float64[:, :], boolean[:])")
def three_rail_forward_kinematics_batch_kernel(bars, q, side, positions, ok):
    """``three_rail_forward_kinematics_kernel`` on every row of ``q`` (N, 3) into
    ``positions`` (N, 3), NaN where it failed (``ok`` False)."""
    for i in range(q.shape[0]):
        px, py, pz, code, _ = three_rail_forward_kinematics_kernel(bars, q[i, 0], q[i, 1], q[i, 2], side)
        ok[i] = code == TRI_OK
        if ok[i]:
            positions[i, 0], positions[i, 1], positions[i, 2] = px, py, pz
        else:
            positions[i, 0] = positions[i, 1] = positions[i, 2] = math.nan


@kernel("(float64[:, :], int64, float64, float64, float64, UniTuple(float64, 9))")
def inverse_kinematics_kernel(bars, m, px, py, pz, r):
    """``actuators_into`` at one pose (floats; R row-major), a new array: (q (m,),
    code, bar); the per-cycle form."""
    q = np.empty(m)
    code, bar = actuators_into(bars, px, py, pz, r, q)
    return q, code, bar


@kernel("(float64[:, :], float64, float64, float64, UniTuple(float64, 9), float64[:])")
def bar_vectors_kernel(bars, px, py, pz, r, q):
    """e_k = B_k - A_k of every bar (n, 3) at the pose and actuators ``q``: the rows
    of the parallel Jacobian A of a translating machine (Orthoglide eq. 4)."""
    out = np.empty((bars.shape[0], 3))
    for k in range(bars.shape[0]):
        out[k, 0], out[k, 1], out[k, 2], _, _, _ = bar_vector(bars, k, px, py, pz, r, q)
    return out


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64, int64, float64)")
def forward_kinematics_kernel(bars, q, p, rot, tol_m, max_iterations, divergence_limit):
    """The platform pose of the actuator values ``q``, from the pose in ``p`` (3,)
    and ``rot`` (9, row-major), both updated in place. Newton with 6 bars,
    Gauss-Newton (J^T J dx = -J^T r) with more, on r_k = |e_k| - l_k.

    Returns (code, iterations, misfit): FK_CONVERGED when every misfit is <= tol_m
    (exactly determined) or the step fell below tol_m (least squares: the misfit left
    is the actuators' inconsistency, the root sum of squares in metres);
    FK_NO_CONVERGENCE after ``max_iterations``; FK_DIVERGED when a misfit passed
    ``divergence_limit``; FK_SINGULAR when J (J^T J) has no inverse; FK_STALLED when
    the misfit grew twice in a row."""
    n = bars.shape[0]
    px, py, pz = p[0], p[1], p[2]
    r = (rot[0], rot[1], rot[2], rot[3], rot[4], rot[5], rot[6], rot[7], rot[8])
    work = np.empty(7 * n + 84)          # the scratch arrays, one allocation
    jac = work[:6 * n].reshape((n, 6))
    res = work[6 * n:7 * n]
    normal = work[7 * n:7 * n + 36].reshape((6, 6))
    inverse = work[7 * n + 36:7 * n + 72].reshape((6, 6))
    g = work[7 * n + 72:7 * n + 78]
    step = work[7 * n + 78:7 * n + 84]
    previous, growth, misfit = math.inf, 0, math.inf
    code, iterations = FK_NO_CONVERGENCE, max_iterations
    for iteration in range(max_iterations + 1):
        # the misfits and the rows of the unit pose Jacobian in one pass over the bars
        # (``unit_row``; the rows of the last, converged, pass go unused)
        worst, squares, degenerate = 0.0, 0.0, False
        for k in range(n):
            length, ux, uy, uz, mx, my, mz = unit_row(bars, k, px, py, pz, r, q)
            jac[k, 0], jac[k, 1], jac[k, 2], jac[k, 3], jac[k, 4], jac[k, 5] = ux, uy, uz, mx, my, mz
            degenerate = degenerate or not length > 0.0
            res[k] = length - bar_length(bars, k, q)
            squares += res[k] * res[k]
            if not abs(res[k]) <= worst:           # (NaN propagates)
                worst = abs(res[k])
        misfit = math.sqrt(squares)
        if worst <= tol_m:
            code, iterations = FK_CONVERGED, iteration
            break
        if iteration == max_iterations:
            break
        if not math.isfinite(worst) or worst > divergence_limit:
            code, iterations = FK_DIVERGED, iteration
            break
        growth = growth + 1 if misfit > previous * (1.0 + 1e-9) else 0
        if growth >= 2:
            code, iterations = FK_STALLED, iteration
            break
        previous = misfit
        if degenerate:                              # a bar of zero length: no direction
            code, iterations = FK_SINGULAR, iteration
            break
        if n == 6:                                  # Newton: dx = -J^-1 r
            for i in range(6):
                for j in range(6):
                    normal[i, j] = jac[i, j]
                g[i] = res[i]
        else:                                       # Gauss-Newton: dx = -(J^T J)^-1 J^T r
            for i in range(6):
                g[i] = 0.0
                for k in range(n):
                    g[i] += jac[k, i] * res[k]
                for j in range(6):
                    s = 0.0
                    for k in range(n):
                        s += jac[k, i] * jac[k, j]
                    normal[i, j] = s
        if not invert6_into(normal, inverse):
            code, iterations = FK_SINGULAR, iteration
            break
        for i in range(6):
            step[i] = 0.0
            for j in range(6):
                step[i] -= inverse[i, j] * g[j]
        px, py, pz = px + step[0], py + step[1], pz + step[2]
        r = mul3_kernel(exp_so3_kernel(step[3], step[4], step[5]), r)
        if n > 6:
            size = 0.0
            for i in range(6):
                size = max(size, abs(step[i]))
            if size <= tol_m:                       # least squares: the minimum of the misfit
                worst, squares = 0.0, 0.0
                for k in range(n):
                    ex, ey, ez, _, _, _ = bar_vector(bars, k, px, py, pz, r, q)
                    rk = math.sqrt(ex * ex + ey * ey + ez * ez) - bar_length(bars, k, q)
                    squares += rk * rk
                misfit = math.sqrt(squares)
                code, iterations = FK_CONVERGED, iteration + 1
                break
    p[0], p[1], p[2] = px, py, pz
    for k in range(9):
        rot[k] = r[k]
    return code, iterations, misfit


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64[:, :], boolean, float64[:, :], boolean, float64, "
        "int64, float64)")
def chord_forward_kinematics_kernel(bars, q, p, rot, jh, have_jh, rows, rows_each_pass, tol_m, max_iterations,
                                    divergence_limit):
    """``forward_kinematics_kernel`` for six bars with chord steps, the solver of a
    stream of small moves (the Gough metrology's DKM, MoM3 §6.3): Newton on
    r_k = l_k - |e_k|, the step [dp; dw] = J_h r, p += dp, R <- exp([dw]x) R, with
    J_h (``jh``, valid when ``have_jh``; ``pose_from_lengths_jacobian_into``) kept
    from earlier steps and solves and re-evaluated only when an iteration gains less
    than three orders of magnitude. ``p`` (3,), ``rot`` (9, row-major) and ``jh``
    (6, 6) are updated in place. ``rows`` (6, 6): the unit pose Jacobian J_h^-1 that
    an evaluation of J_h inverts. With ``rows_each_pass`` every pass makes the
    residuals and the rows together (``unit_row``), and ``rows`` ends holding J_h^-1
    at the returned pose (but after FK_SINGULAR): for solves that evaluate J_h and
    have their branch checked anyway (a batch, a cold start), no pass of their own.
    Without, a pass makes the rows only where J_h is evaluated (a warm stream: most
    solves keep J_h, and the rows would double a pass's cost). Returns (code, iterations, evaluations, residual,
    have_jh): FK_CONVERGED (every |r_k| <= tol_m), FK_NO_CONVERGENCE, FK_DIVERGED
    (a residual above ``divergence_limit``), FK_STALLED (it grew twice in a row),
    FK_SINGULAR (J_h has no inverse, or there are not six bars)."""
    if bars.shape[0] != 6:
        return FK_SINGULAR, 0, 0, math.inf, have_jh
    px, py, pz = p[0], p[1], p[2]
    r = (rot[0], rot[1], rot[2], rot[3], rot[4], rot[5], rot[6], rot[7], rot[8])
    res = np.empty(6)
    evaluations = 0
    previous = math.inf
    growth = 0
    residual = math.inf
    code = FK_NO_CONVERGENCE
    iterations = max_iterations
    for iteration in range(max_iterations + 1):
        residual = 0.0
        with_rows = rows_each_pass or not have_jh          # (without J_h this pass evaluates it)
        for k in range(6):
            if with_rows:
                length, rows[k, 0], rows[k, 1], rows[k, 2], rows[k, 3], rows[k, 4], rows[k, 5] = \
                    unit_row(bars, k, px, py, pz, r, q)
            else:
                ex, ey, ez, _, _, _ = bar_vector(bars, k, px, py, pz, r, q)
                length = math.sqrt(ex * ex + ey * ey + ez * ez)
            res[k] = bar_length(bars, k, q) - length
            if not abs(res[k]) <= residual:       # (NaN propagates)
                residual = abs(res[k])
        if residual <= tol_m:
            code, iterations = FK_CONVERGED, iteration
            break
        if iteration == max_iterations:
            break
        if not math.isfinite(residual) or residual > divergence_limit:
            code, iterations = FK_DIVERGED, iteration
            break
        growth = growth + 1 if residual > previous else 0
        if growth >= 2:
            code, iterations = FK_STALLED, iteration
            break
        if not have_jh or residual > 1e-3 * previous:
            evaluations += 1
            # J_h = (J_h^-1)^-1: of the rows this pass made (a bar of zero length has a
            # zero row: singular too), or made now
            if not (invert6_into(rows, jh) if with_rows else
                    pose_from_lengths_jacobian_into(bars, px, py, pz, r, q, jh, rows)):
                code, iterations = FK_SINGULAR, iteration
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


@kernel()
def rail_closure_rows_into(bars, px, py, pz, r, q, out) -> bool:
    """The closure Jacobian of the bars for the unknowns (w, q) at a given platform
    position: row k = [(R b_k) x e_k / |e_k|, -(e_k . u_k) / |e_k| in the column of
    bar k's actuator] (d|e_k|/dt with p held; MACHINE_MODEL.md's J_x, J_q). ``out``
    (n, 3 + m). False where a bar has zero length."""
    m = out.shape[1] - 3
    for k in range(bars.shape[0]):
        n, ux, uy, uz, out[k, 0], out[k, 1], out[k, 2] = unit_row(bars, k, px, py, pz, r, q)
        if not n > 0.0:
            return False
        for j in range(m):
            out[k, 3 + j] = 0.0
        j = int(bars[k, COL_ACTUATOR])
        if j >= 0 and bars[k, COL_TYPE] == 0.0:
            out[k, 3 + j] = -(ux * bars[k, COL_U] + uy * bars[k, COL_U + 1] + uz * bars[k, COL_U + 2])
    return True


@kernel("(float64[:, :], float64[:], float64[:], float64[:], float64, int64)")
def inverse_kinematics_parasitic_kernel(bars, p, rot, q, tol_m, max_iterations):
    """Inverse kinematics of a machine whose task is the platform position only and
    whose rotation follows from the bars (the Delta's parallelograms; with unequal
    bars, MoM3 §4.1's imperfect case, the parasitic rotation): Newton on the bar
    misfits r_k = |e_k| - L_k over (w, q) with p held, from ``rot`` and the first
    bars' closed form; needs as many bars as 3 + actuators (6 for a Delta).
    ``rot`` (9) and ``q`` are updated in place. Returns (code, iterations, misfit):
    FK_* codes (FK_CONVERGED, FK_NO_CONVERGENCE, FK_SINGULAR, FK_DIVERGED), and
    IK_UNREACHABLE + 10 when a rail cannot reach its joint at the start."""
    n = bars.shape[0]
    m = q.shape[0]
    if n != 3 + m or n != 6:
        return FK_SINGULAR, 0, math.inf
    code, _ = inverse_kinematics_into(bars, p, rot, q)
    if code != IK_OK:
        return IK_UNREACHABLE + 10, 0, math.inf
    r = (rot[0], rot[1], rot[2], rot[3], rot[4], rot[5], rot[6], rot[7], rot[8])
    jac = np.empty((6, 6))
    inverse = np.empty((6, 6))
    res = np.empty(6)
    misfit = math.inf
    result, iterations = FK_NO_CONVERGENCE, max_iterations
    for iteration in range(max_iterations + 1):
        worst = 0.0
        for k in range(6):
            ex, ey, ez, _, _, _ = bar_vector(bars, k, p[0], p[1], p[2], r, q)
            res[k] = math.sqrt(ex * ex + ey * ey + ez * ez) - bar_length(bars, k, q)
            if not abs(res[k]) <= worst:
                worst = abs(res[k])
        misfit = worst
        if worst <= tol_m:
            result, iterations = FK_CONVERGED, iteration
            break
        if iteration == max_iterations:
            break
        if not math.isfinite(worst) or worst > 1.0:
            result, iterations = FK_DIVERGED, iteration
            break
        if not rail_closure_rows_into(bars, p[0], p[1], p[2], r, q, jac) or not invert6_into(jac, inverse):
            result, iterations = FK_SINGULAR, iteration
            break
        dw0 = dw1 = dw2 = 0.0
        for j in range(6):
            dw0 -= inverse[0, j] * res[j]
            dw1 -= inverse[1, j] * res[j]
            dw2 -= inverse[2, j] * res[j]
        for a in range(m):
            d = 0.0
            for j in range(6):
                d -= inverse[3 + a, j] * res[j]
            q[a] += d
        r = mul3_kernel(exp_so3_kernel(dw0, dw1, dw2), r)
    for k in range(9):
        rot[k] = r[k]
    return result, iterations, misfit


@kernel()
def extrapolated_pose_into(p1, r1, p0, r0, p, rot):
    """The guess of a warm-started solve along a stream, from its last two solutions
    (p1, R1) and (p0, R0) (R row-major (9,)): p = 2 p1 - p0; R = exp(w) R1 with w the
    rotation vector of R1 R0^T (exact to O(w^3)), into ``p`` and ``rot``. From it one
    Newton step closes a smooth stream's reading where the last solution needs two."""
    for k in range(3):
        p[k] = 2.0 * p1[k] - p0[k]
    b = (r1[0], r1[1], r1[2], r1[3], r1[4], r1[5], r1[6], r1[7], r1[8])
    d = mul3_kernel(b, (r0[0], r0[3], r0[6], r0[1], r0[4], r0[7], r0[2], r0[5], r0[8]))
    g = mul3_kernel(exp_so3_kernel(0.5 * (d[7] - d[5]), 0.5 * (d[2] - d[6]), 0.5 * (d[3] - d[1])), b)
    for k in range(9):
        rot[k] = g[k]


# A warm-started stream's state (StrutFK), one array: the last good pose (p1, R1
# row-major) and the one before (p0, R0); flags[0]: whether (p0, R0) is there.
WARM_P1, WARM_R1, WARM_P0, WARM_R0, WARM_STATE_SIZE = 0, 3, 12, 15, 24


@kernel()
def advance_warm_state(state, p, rot, has_previous):
    """A warm state after a good solve (p, rot): (p0, R0) <- (p1, R1), or the solution
    itself when there was no previous one; (p1, R1) <- the solution."""
    if has_previous:
        state[WARM_P0:WARM_STATE_SIZE] = state[WARM_P1:WARM_P0]
    else:
        state[WARM_P0:WARM_R0] = p
        state[WARM_R0:WARM_STATE_SIZE] = rot
    state[WARM_P1:WARM_R1] = p
    state[WARM_R1:WARM_P0] = rot


@kernel("(float64[:, :], float64[:], float64[::1], int64[:], float64, int64, float64, float64[::1], "
        "float64[:, ::1])")
def forward_kinematics_warm_kernel(bars, q, state, flags, tol_m, max_iterations, divergence_limit, p, rotation):
    """One reading of a stream: ``forward_kinematics_kernel`` from the guess
    extrapolated from the last two solutions (``extrapolated_pose_into``; the last
    solution itself when there is one only), the last iterate into ``p`` (3,) and
    ``rotation`` (3, 3). The state moves on only when it converged; after a failure
    the next guess is the last good pose. Returns (code, iterations, misfit)."""
    p1, r1 = state[WARM_P1:WARM_R1], state[WARM_R1:WARM_P0]
    p0, r0 = state[WARM_P0:WARM_R0], state[WARM_R0:WARM_STATE_SIZE]
    rot = rotation.reshape(9)
    has_previous = flags[0] != 0
    if has_previous:
        extrapolated_pose_into(p1, r1, p0, r0, p, rot)
    else:
        p[:] = p1
        rot[:] = r1
    code, iterations, misfit = forward_kinematics_kernel(bars, q, p, rot, tol_m, max_iterations, divergence_limit)
    if code == FK_CONVERGED:
        advance_warm_state(state, p, rot, has_previous)
        flags[0] = 1
    else:
        flags[0] = 0
    return code, iterations, misfit


@kernel("(float64[:, :], float64[:, :], float64[::1], int64[:], float64, int64, float64, float64[:, :], "
        "int64[:], int64[:], float64[:])")
def forward_kinematics_stream_kernel(bars, lengths, state, flags, tol_m, max_iterations, divergence_limit, poses,
                                     codes, iterations, misfits):
    """``forward_kinematics_warm_kernel`` over a stream of readings (N, n) in one
    compiled loop, bit for bit N calls of it: ``poses`` (N, 12) = p and R row-major,
    with each reading's code, iterations and misfit."""
    p, rotation = np.empty(3), np.empty((3, 3))
    rot = rotation.reshape(9)
    for k in range(lengths.shape[0]):
        code, its, misfit = forward_kinematics_warm_kernel(bars, lengths[k], state, flags, tol_m, max_iterations,
                                                           divergence_limit, p, rotation)
        codes[k], iterations[k], misfits[k] = code, its, misfit
        poses[k, 0:3] = p
        poses[k, 3:12] = rot


__all__ = ["IK_CODES", "IKCode", "THREE_SPHERES_CODES", "ThreeSpheresCode", "VELOCITY_TERMS_CODES", "VelocityTermsCode",
           "BAR_COLUMNS", "COL_A", "COL_ACTUATOR", "COL_B", "COL_BRANCH", "COL_LENGTH", "COL_TYPE", "COL_U", "FK_CONVERGED", "FK_DIVERGED", "FK_NO_CONVERGENCE", "FK_SINGULAR", "FK_STALLED",
           "IK_OK", "IK_UNREACHABLE", "actuators_into", "inverse_kinematics_batch_kernel", "RAIL", "STRUT", "VT_OK", "VT_SINGULAR", "VT_UNREACHABLE", "actuator_of_bar",
           "TRI_COLLINEAR", "TRI_NOT_MEETING", "TRI_OK", "TRI_OTHER_BRANCH", "inverse_kinematics_kernel",
           "three_rail_forward_kinematics_batch_kernel", "three_rail_forward_kinematics_kernel",
           "bar_length", "bar_rows", "bar_vector", "bar_vectors_kernel", "rail_jacobian_batch_kernel",
           "rail_jacobian_derivative_kernel", "rail_row_terms", "rail_task_inverse_kinematics_kernel", "rail_task_jacobian_derivative_kernel",
           "rail_task_velocity_terms_kernel", "rail_velocity_terms_into", "rail_velocity_terms_kernel",
           "task_pose_twist",
           "chord_forward_kinematics_kernel", "forward_kinematics_kernel", "forward_kinematics_stream_kernel",
           "forward_kinematics_warm_kernel", "advance_warm_state", "extrapolated_pose_into", "inverse_kinematics_into", "inverse_kinematics_parasitic_kernel",
           "invert6_into", "pose_from_lengths_jacobian_into", "pose_from_lengths_jacobian_kernel",
           "rail_closure_rows_into", "strut_lengths_batch_kernel", "strut_lengths_into", "strut_lengths_kernel",
           "unit_pose_jacobian_batch_kernel", "unit_pose_jacobian_into"]
