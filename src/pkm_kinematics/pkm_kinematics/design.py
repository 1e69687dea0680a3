"""Design sweeps: kinematic variants of a machine, each evaluated over a workspace grid
(pure numpy/numba; pkm_studies.design_study runs them in chunks on Dask).

Sliding Star §2: the team evaluated about 50 structural and several hundred thousand
parametric variants to choose TriJoint's and Sliding Star's geometry. Here a variant is
the base machine with some of its dimensions changed (``PARAMETERS``, one registry per
kind of design) and its figures of merit are computed over the base machine's
workspace (the task it must do):

Planar machines (ARCHI, Sliding Star), ``planar_metrics``, over a grid of (x, y, theta):

- ``reach``: the share of the grid where every leg assembles on its branch and none is
  perpendicular to its rail (ARCHI §3.1; the joint limits of the base machine are not
  imposed: the drive travel is what the design must provide, below);
- ``cond_min``, ``cond_max``: the 2-norm condition number of J_m over the reachable
  poses (ARCHI §3.3, Fig. 10), ``inf`` at a parallel singularity;
- ``failure_cond_max``: for a redundant machine (n > 3), the condition number of the
  machine left after the loss of any one drive (its n - 1 legs), at its worst over the
  poses and over which drive is lost: how well it can go on after a drive failure,
  whichever fails (ARCHI §4.2); NaN for n = 3 (it cannot);
- ``travel_max_m``: the largest carriage travel (max - min of q_i) a drive needs;
- ``tf_min``, ``tf_max``: the velocity transmission factors psi = 1 / sigma(J_m), the
  tool speed per unit drive speed (Orthoglide §4.3, as translational.transmission_factors),
  at their extremes over the poses.

The Gough metrology (MoM3 §5.2 parametrisation: r_b, r_tp, alpha_b, alpha_tp),
``gough_metrics``: the worst tool-level resolution C_opt (MoM3 eq. 20-21) and the worst
position resolution over the workspace cube, and the strut length range (the struts
fit their limits or not).

``pareto_front``: the variants no other variant beats in every objective.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from .analysis import cube_points, gough_design_figures, workspace_grid
from .distribution import gram_rows
from .errors import FieldError
from .jit import kernel
from . import bars as B
from .rails import PLANAR_COLUMNS, RailMachine

# ------------------------------------------------------------------ parameters
# name -> (what it changes, the open interval of its values)
PLANAR_PARAMETERS = {
    "link_length_scale": ("every link length times this factor", (0.0, 10.0)),
    "platform_scale": ("every platform point (b_i, from the platform centre) times this factor", (0.0, 10.0)),
    "rail_spacing_scale": ("every rail moved along its normal: its distance from the home position times this "
                           "factor", (0.0, 10.0)),
}
GOUGH_PARAMETERS = {
    "r_base_m": ("radius of the base joints (MoM3 §5.2 r_b)", (0.0, 10.0)),
    "r_plate_m": ("radius of the plate joints (r_tp)", (0.0, 10.0)),
    "alpha_base_deg": ("angle between the two base joints of a pair (alpha_b)", (0.0, 120.0)),
    "alpha_plate_deg": ("angle between the two plate joints of a pair (alpha_tp)", (0.0, 120.0)),
}
PARAMETERS = {"planar": PLANAR_PARAMETERS, "gough": GOUGH_PARAMETERS}
NEAR_DOUBLE = 0.99          # |r| of Smith's formula beyond which two eigenvalues are nearly equal
ILL_CONDITIONED = 1e-6      # smallest / largest eigenvalue under which the smallest is deflated
PLANAR_METRICS = ("reach", "cond_min", "cond_max", "failure_cond_max", "travel_max_m", "tf_min", "tf_max")
GOUGH_METRICS = ("tool_resolution_m", "position_resolution_m", "strut_min_m", "strut_max_m", "struts_fit")
METRICS = {"planar": PLANAR_METRICS, "gough": GOUGH_METRICS}


def check_parameters(kind: str, names) -> None:
    """ValueError naming the first parameter the kind of design does not have."""
    known = PARAMETERS[kind]
    for name in names:
        if name not in known:
            raise FieldError(name, f"not a {kind} design parameter; known: {', '.join(known)}")


# ------------------------------------------------------------------ conditioning
@kernel()
def symmetric3_eigen_extremes(a00, a01, a02, a11, a12, a22):
    """(smallest, largest) eigenvalue of the symmetric 3x3 matrix [[a00, a01, a02],
    [., a11, a12], [., ., a22]]. The largest in closed form (O. K. Smith, "Eigenvalues
    of a symmetric 3 x 3 matrix", CACM 4(4), 1961): with q = tr/3, p = sqrt(|A - q I|_F^2
    / 6), r = det((A - q I) / p) / 2, the eigenvalues are q + 2 p cos(acos(r)/3 + 2 pi k/3).
    Where two eigenvalues nearly coincide (|r| > NEAR_DOUBLE: acos loses ~sqrt(eps)) or
    the smallest is tiny (under ILL_CONDITIONED of the largest, where Smith's absolute
    error ~eps of the largest is a large part of it), the smallest is taken otherwise:
    the two larger nearly equal, as det A / (largest middle); else from the 2 x 2 matrix
    A is on the plane normal to the largest's eigenvector (deflation; its smaller
    eigenvalue as det / larger). Checked against numpy: the smallest to 1e-6 relative
    down to 1e-8 of the largest (cond(J) = 1e4), the largest to 1e-8 (sqrt(eps) where
    it is nearly double: harmless to a condition number)."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    d0, d1, d2 = a00 - q, a11 - q, a22 - q
    p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1
    if p2 <= 0.0:
        return q, q                                   # a multiple of the identity
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22, b01, b02, b12 = d0 / p, d1 / p, d2 / p, a01 / p, a02 / p, a12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(1.0, max(-1.0, r))
    phi = math.acos(r) / 3.0
    largest = q + 2.0 * p * math.cos(phi)
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    if abs(r) < NEAR_DOUBLE and smallest > ILL_CONDITIONED * largest:
        return smallest, largest                  # no two eigenvalues close, none tiny: Smith's is accurate
    if r <= -NEAR_DOUBLE:                         # the two larger nearly equal (r = -1): det A / (largest middle)
        middle = 3.0 * q - largest - smallest
        det = a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02)
        return (det / (largest * middle) if middle > 0.0 else smallest), largest
    # its eigenvector: the longest cross product of two rows of A - largest I
    r0x, r0y, r0z = a00 - largest, a01, a02
    r1x, r1y, r1z = a01, a11 - largest, a12
    r2x, r2y, r2z = a02, a12, a22 - largest
    best, vx, vy, vz = -1.0, 0.0, 0.0, 0.0
    for ax, ay, az, bx, by, bz in ((r0x, r0y, r0z, r1x, r1y, r1z), (r0x, r0y, r0z, r2x, r2y, r2z),
                                   (r1x, r1y, r1z, r2x, r2y, r2z)):
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        norm2 = cx * cx + cy * cy + cz * cz
        if norm2 > best:
            best, vx, vy, vz = norm2, cx, cy, cz
    if best <= 0.0:                                   # the two smaller coincide with it: A = q I
        return q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0), largest
    norm = math.sqrt(best)
    vx, vy, vz = vx / norm, vy / norm, vz / norm
    # an orthonormal pair (u, w) of the plane normal to v
    if abs(vx) <= abs(vy) and abs(vx) <= abs(vz):
        ux, uy, uz = 0.0, -vz, vy
    elif abs(vy) <= abs(vz):
        ux, uy, uz = vz, 0.0, -vx
    else:
        ux, uy, uz = -vy, vx, 0.0
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / norm, uy / norm, uz / norm
    wx, wy, wz = vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux
    aux, auy, auz = a00 * ux + a01 * uy + a02 * uz, a01 * ux + a11 * uy + a12 * uz, a02 * ux + a12 * uy + a22 * uz
    awx, awy, awz = a00 * wx + a01 * wy + a02 * wz, a01 * wx + a11 * wy + a12 * wz, a02 * wx + a12 * wy + a22 * wz
    buu = ux * aux + uy * auy + uz * auz
    bww = wx * awx + wy * awy + wz * awz
    buw = ux * awx + uy * awy + uz * awz
    half = 0.5 * (buu - bww)
    larger = 0.5 * (buu + bww) + math.sqrt(half * half + buw * buw)
    if larger <= 0.0:
        return 0.0, largest
    return (buu * bww - buw * buw) / larger, largest


@kernel()
def _gram_cond(rows):
    """(condition number, sigma_min, sigma_max) of J = ``rows`` (m, 3), from the
    eigenvalues of J^T J (distribution.gram_rows); cond inf when J^T J is singular to
    ~1e-14."""
    a00, a01, a02, a11, a12, a22 = gram_rows(rows)
    lo, hi = symmetric3_eigen_extremes(a00, a01, a02, a11, a12, a22)
    s_hi = math.sqrt(max(hi, 0.0))
    if lo <= 1e-14 * hi:
        return math.inf, math.sqrt(max(lo, 0.0)), s_hi
    s_lo = math.sqrt(lo)
    return s_hi / s_lo, s_lo, s_hi


@kernel("(float64[:, :, :], float64[:, :], int64[:, :])")
def planar_metrics_kernel(bars, poses, subsets):
    """PLANAR_METRICS of each variant, (V, 7): ``bars`` (V, n, BAR_COLUMNS), each
    variant's rail bars in the plane z = 0 (``planar_variants``), ``poses`` (P, 3),
    ``subsets`` (S, m) the legs left after each single drive failure (S = 0: not
    redundant). J_m and q per pose are ``bars.rail_velocity_terms_into``'s."""
    n_var, n, n_pose = bars.shape[0], bars.shape[1], poses.shape[0]
    m = subsets.shape[1]
    out = np.empty((n_var, 7))
    rows = np.empty((n, 3))
    left = np.empty((m, 3))                       # the rows of the machine left after a failure
    q = np.empty(n)
    qdot, bias, no_rates = np.empty(n), np.empty(n), np.empty((0, 3))
    qmin = np.empty(n)
    qmax = np.empty(n)
    columns = PLANAR_COLUMNS                      # planar: vx, vy, wz
    rest = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    cs = np.empty((n_pose, 2))
    for p in range(n_pose):
        cs[p, 0], cs[p, 1] = math.cos(poses[p, 2]), math.sin(poses[p, 2])
    for v in range(n_var):
        variant = bars[v]
        reach = 0
        cmin, cmax, sub_worst, sigma_lo, sigma_hi = math.inf, 0.0, 0.0, math.inf, 0.0
        qmin[:] = math.inf
        qmax[:] = -math.inf
        for p in range(n_pose):
            c, s = cs[p, 0], cs[p, 1]
            code, _ = B.rail_velocity_terms_into(variant, poses[p, 0], poses[p, 1], 0.0,
                                                 (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0), rest, columns, q, rows,
                                                 qdot, bias, no_rates)
            if code != B.VT_OK:
                continue
            reach += 1
            for k in range(n):
                qmin[k] = min(qmin[k], q[k])
                qmax[k] = max(qmax[k], q[k])
            cond, s_lo, s_hi = _gram_cond(rows)
            cmin, cmax = min(cmin, cond), max(cmax, cond)
            sigma_lo, sigma_hi = min(sigma_lo, s_lo), max(sigma_hi, s_hi)
            for t in range(subsets.shape[0]):
                for r in range(m):
                    k = subsets[t, r]
                    left[r, 0], left[r, 1], left[r, 2] = rows[k, 0], rows[k, 1], rows[k, 2]
                sub_worst = max(sub_worst, _gram_cond(left)[0])
        travel = 0.0
        for k in range(n):
            travel = max(travel, qmax[k] - qmin[k])
        if reach == 0:
            out[v, :] = math.nan
            out[v, 0] = 0.0
        else:
            out[v, 0], out[v, 1], out[v, 2] = reach / n_pose, cmin, cmax
            out[v, 3] = sub_worst if subsets.shape[0] else math.nan
            # psi = 1 / sigma: the smallest psi from the largest sigma (0 at a serial singularity)
            out[v, 4] = travel
            out[v, 5] = 1.0 / sigma_hi if sigma_hi > 0.0 else math.inf
            out[v, 6] = 1.0 / sigma_lo if sigma_lo > 0.0 else math.inf
    return out


# ------------------------------------------------------------------ planar variants
def planar_variants(machine: RailMachine, names, values) -> np.ndarray:
    """The rail bars of each variant, (V, n, BAR_COLUMNS) in the plane z = 0
    (``bars.bar_rows``, as ``RailMachine.bars``), from ``values`` (V, len(names)) of
    PLANAR_PARAMETERS applied to the base machine (its public legs and home pose)."""
    check_parameters("planar", names)
    values = np.atleast_2d(np.asarray(values, dtype=float))
    legs = machine.legs
    o = np.array([leg.rail_origin for leg in legs], dtype=float)
    u = np.array([leg.rail_direction for leg in legs], dtype=float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    length = np.array([leg.link_length for leg in legs], dtype=float)
    b = np.array([leg.platform_point for leg in legs], dtype=float)
    sigma = np.array([float(leg.assembly) for leg in legs])
    n_var = values.shape[0]
    o_v, b_v = np.broadcast_to(o, (n_var, *o.shape)).copy(), np.broadcast_to(b, (n_var, *b.shape)).copy()
    length_v = np.broadcast_to(length, (n_var, len(legs))).copy()
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1)                  # each rail's normal
    offset = ((o - machine.home[:2]) * normal).sum(axis=1)     # its distance from home, signed
    for j, name in enumerate(names):
        f = values[:, j:j + 1]
        if name == "link_length_scale":
            length_v *= f
        elif name == "platform_scale":
            b_v *= f[:, :, None]
        else:                                                       # rail_spacing_scale
            o_v += ((f - 1.0) * offset)[:, :, None] * normal
    flat = np.zeros((n_var, len(legs), 1))                           # the plane z = 0
    out = np.empty((n_var, len(legs), B.BAR_COLUMNS))
    for v in range(n_var):
        out[v] = B.bar_rows(np.concatenate([o_v[v], flat[v]], axis=1), np.concatenate([b_v[v], flat[v]], axis=1),
                            actuator=np.arange(len(legs)), kind=B.RAIL, rail=np.concatenate([u, flat[v]], axis=1),
                            length=length_v[v], branch=sigma)
    return out


def workspace_poses(machine: RailMachine, points_per_axis: int = 11, theta_points: int = 9) -> np.ndarray:
    """The base machine's workspace grid (analysis.workspace_grid), contiguous."""
    return np.ascontiguousarray(workspace_grid(machine, points_per_axis, theta_points), dtype=float)


def remaining_legs(n_legs: int) -> np.ndarray:
    """The legs left after the loss of each one drive, (n, n - 1); (0, n - 1) when the
    machine is not redundant (n = 3: it cannot go on)."""
    if n_legs <= 3:
        return np.zeros((0, n_legs - 1), dtype=np.int64)
    return np.array(list(itertools.combinations(range(n_legs), n_legs - 1)), dtype=np.int64)


def planar_metrics(machine: RailMachine, names, values, poses) -> dict[str, np.ndarray]:
    """PLANAR_METRICS of the variants (module docstring), each an array (V,)."""
    bars = np.ascontiguousarray(planar_variants(machine, names, values))
    out = planar_metrics_kernel(bars, np.ascontiguousarray(poses, dtype=float), remaining_legs(machine.n_legs))
    return dict(zip(PLANAR_METRICS, out.T))


# ------------------------------------------------------------------ Gough variants
def gough_metrics(metrology, names, values, points_per_axis: int = 3) -> dict[str, np.ndarray]:
    """GOUGH_METRICS of MoM3-parametrised Gough platforms, one per row of ``values``
    (V, len(names)); parameters not named keep ``metrology``'s design values."""
    check_parameters("gough", names)
    values = np.atleast_2d(np.asarray(values, dtype=float))
    base = dict(zip(GOUGH_PARAMETERS, metrology.design_parameters()))
    positions = cube_points(metrology.workspace_center, metrology.workspace_size_m, points_per_axis)
    out = {k: np.empty(len(values)) for k in GOUGH_METRICS}
    for v, row in enumerate(values):
        p = {**base, **dict(zip(names, row))}
        fig = gough_design_figures(p["r_base_m"], p["r_plate_m"], p["alpha_base_deg"], p["alpha_plate_deg"],
                                   metrology.encoder_resolution_m, metrology.tool_box, positions,
                                   metrology.platform.strut_limits, metrology.workspace_center,
                                   metrology.geometry.get("plate_line_offset_deg", 60.0))
        for k, value in zip(GOUGH_METRICS, fig):
            out[k][v] = value
    return out


# ------------------------------------------------------------------ Pareto front
def pareto_front(objectives, senses) -> np.ndarray:
    """Mask of the non-dominated rows of ``objectives`` (N, k): a row is dominated when
    another is at least as good in every objective and better in one (``senses``:
    "min" or "max" per column). Rows with a NaN are never on the front. Rows are taken
    best-first by their rank sum, each checked against the front so far: O(N F)."""
    x = np.asarray(objectives, dtype=float)
    if x.ndim != 2 or x.shape[1] != len(senses):
        raise FieldError("objectives", f"expected (N, {len(senses)}), got {x.shape}")
    for s in senses:
        if s not in ("min", "max"):
            raise FieldError("senses", f"'min' or 'max', got {s!r}")
    x = np.where(np.array([s == "max" for s in senses]), -x, x)       # all minimised
    valid = ~np.isnan(x).any(axis=1)
    mask = np.zeros(len(x), dtype=bool)
    order = np.flatnonzero(valid)
    ranks = np.argsort(np.argsort(x[order], axis=0), axis=0).sum(axis=1)
    front: list[int] = []
    for i in order[np.argsort(ranks, kind="stable")]:
        if front:
            f = x[front]
            if np.any(np.all(f <= x[i], axis=1) & np.any(f < x[i], axis=1)):
                continue
            # a row that dominates another has the smaller rank sum, but ties get arbitrary
            # ranks (argsort), so a later row may still dominate a kept one: drop those
            beaten = np.all(x[i] <= f, axis=1) & np.any(x[i] < f, axis=1)
            if beaten.any():
                front = [j for j, b in zip(front, beaten) if not b]
        front.append(int(i))
    mask[front] = True
    return mask
