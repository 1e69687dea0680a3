"""Analyses vectorised over batches of poses: conditioning, reachability, singular
angles of sub-machines, Gough metrology resolution and its optimisation, Orthoglide
sizing. Each function names the paper section it reproduces.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from .errors import FieldError
from .gough import GoughPlatform, mom3_points
from .measures import condition_numbers
from .rails import RailLeg, RailMachine
from .task_space import PLANAR, POSITION


# ------------------------------------------------------------ conditioning maps
def singularity_margin(jacobians: np.ndarray) -> np.ndarray:
    """Inverse condition number sigma_min / sigma_max in [0, 1]: 0 at a singularity,
    1 at an isotropic configuration (Orthoglide §4.1)."""
    with np.errstate(divide="ignore"):
        return 1.0 / condition_numbers(jacobians)


def reachability(machine, poses) -> np.ndarray:
    """Mask of poses that assemble and keep every drive inside its joint limits."""
    q, ok = machine.inverse_kinematics_batch(poses)
    return ok & machine.within_joint_limits(np.where(np.isfinite(q), q, np.inf))


def condition_map(machine, poses) -> np.ndarray:
    """Condition number of J_m at each pose; NaN where unreachable or out of limits."""
    cond = machine.condition_number_batch(poses)
    cond[~reachability(machine, poses)] = np.nan
    return cond


def workspace_box(machine, margin_m: float = 0.0) -> list[tuple[float, float]]:
    """(lower, upper) per translation axis of the configured workspace, widened by
    ``margin_m``: planar (x, y), translational (x, y, z) of the cube, a strut
    machine's (x, y, z) of its box."""
    ws = machine.workspace
    if machine.task_space is PLANAR:
        return [(ws["x"][0] - margin_m, ws["x"][1] + margin_m), (ws["y"][0] - margin_m, ws["y"][1] + margin_m)]
    if "half_size" in ws:
        return [(float(c) - float(h) - margin_m, float(c) + float(h) + margin_m)
                for c, h in zip(ws["center"], ws["half_size"])]
    half = 0.5 * float(ws["size"]) + margin_m
    return [(float(c) - half, float(c) + half) for c in ws["center"]]


def task_box(machine, margin_m: float = 0.0, margin_rad: float = 0.0) -> list[tuple[float, float]]:
    """(lower, upper) per task axis a pose must stay in: the translation box
    (workspace_box, widened by ``margin_m``), then a strut machine's angles a, b, c
    within its ``abc_half_range_deg`` about home (widened by ``margin_rad``); a planar
    machine's angle is free. The planner checks its plans against it (no margin), the
    controller the measured pose (with its margins)."""
    box = workspace_box(machine, margin_m)
    ranges = machine.workspace.get("abc_half_range_deg")
    if ranges is not None and machine.task_space.dof == 6:
        home = [float(v) for v in machine.home][3:]
        box += [(h - math.radians(float(r)) - margin_rad, h + math.radians(float(r)) + margin_rad)
                for h, r in zip(home, ranges)]
    return box


def workspace_grid(machine, points_per_axis: int = 11, theta_points: int = 13) -> np.ndarray:
    """A regular grid over the machine's configured workspace (the machine's own
    ``workspace_grid``: (N, 3) poses/positions of a 3-DOF machine, (N, 6) of a hexapod)."""
    return machine.workspace_grid(points_per_axis, theta_points)


@dataclass
class WorkspaceSummary:
    poses: int
    reachable_fraction: float
    condition_min: float
    condition_median: float
    condition_max: float
    worst_pose: list
    joint_range: list            # per drive [min, max] over the reachable poses
    transmission_min: float | None = None
    transmission_max: float | None = None


def workspace_summary(machine, points_per_axis: int = 11, theta_points: int = 13) -> WorkspaceSummary:
    """Reachability, conditioning and drive travel over the configured workspace."""
    poses = workspace_grid(machine, points_per_axis, theta_points)
    reach = reachability(machine, poses)
    cond = condition_map(machine, poses)
    q, _ = machine.inverse_kinematics_batch(poses)
    qr = q[reach]
    finite = np.isfinite(cond)
    worst = poses[np.nanargmax(cond)].tolist() if finite.any() else []
    out = WorkspaceSummary(
        poses=len(poses), reachable_fraction=float(reach.mean()),
        condition_min=float(np.nanmin(cond)) if finite.any() else math.nan,
        condition_median=float(np.nanmedian(cond)) if finite.any() else math.nan,
        condition_max=float(np.nanmax(cond)) if finite.any() else math.nan,
        worst_pose=worst,
        joint_range=[[float(qr[:, i].min()), float(qr[:, i].max())] for i in range(q.shape[1])] if len(qr) else [],
    )
    if isinstance(machine, RailMachine) and machine.task_space is POSITION:     # Orthoglide §4.3: all translations
        psi = machine.transmission_factors_batch(poses[reach])
        out.transmission_min = float(np.nanmin(psi)) if psi.size else math.nan
        out.transmission_max = float(np.nanmax(psi)) if psi.size else math.nan
    return out


# ------------------------------------------------- ARCHI Figure 10 (§3.3)
@dataclass
class ConditionSweep:
    theta_deg: np.ndarray
    full_condition: np.ndarray                  # condition number of the n-leg machine
    sub_condition: dict                         # legs -> condition numbers over theta
    singular_angles_deg: dict                   # legs -> refined angles where det = 0


def sub_machine_determinant(machine: RailMachine, legs, x: float, y: float, theta) -> np.ndarray:
    """det of the 3 x 3 Jacobian of a 3-leg sub-machine, over an array of angles."""
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    poses = np.stack([np.full_like(theta, x), np.full_like(theta, y), theta], axis=1)
    return np.linalg.det(machine.jacobian_batch(poses)[:, list(legs), :])


def condition_sweep(machine: RailMachine, x: float, y: float, theta_min_deg: float,
                    theta_max_deg: float, samples: int = 4001, xtol_deg: float = 1e-9) -> ConditionSweep:
    """ARCHI Figure 10: condition numbers of the redundant machine and of each 3-leg
    sub-machine for a fixed position while the nacelle turns, with every singular
    angle of a sub-machine (sign change of its Jacobian determinant) refined by
    Brent's method to ``xtol_deg``."""
    theta_deg = np.linspace(theta_min_deg, theta_max_deg, samples)
    theta = np.radians(theta_deg)
    poses = np.stack([np.full_like(theta, x), np.full_like(theta, y), theta], axis=1)
    jac = machine.jacobian_batch(poses)
    full = condition_numbers(jac)
    subs, angles = {}, {}
    for legs in machine.sub_machines():
        sub = jac[:, list(legs), :]
        subs[legs] = condition_numbers(sub)
        with np.errstate(invalid="ignore"):        # NaN where the pose is unreachable
            det = np.linalg.det(sub)
        roots = []
        for k in np.nonzero(np.sign(det[:-1]) * np.sign(det[1:]) < 0)[0]:
            root = brentq(lambda t: float(sub_machine_determinant(machine, legs, x, y, t)[0]),
                          theta[k], theta[k + 1], xtol=math.radians(xtol_deg), rtol=1e-15)
            roots.append(math.degrees(root))
        angles[legs] = roots
    return ConditionSweep(theta_deg, full, subs, angles)


# --------------------------------------------------- MoM3 §5.5 resolution
@dataclass
class ResolutionResult:
    position_m: float            # worst ||dp_h|| over the workspace (encoders at +-eps)
    orientation_rad: float       # worst ||dr_h||
    tilt_rad: float              # worst ||(dr_x, dr_y)||: rotation about horizontal axes
    twist_rad: float             # worst |dr_z|: rotation about the vertical axis
    tool_m: float                # worst ||dp_t|| over the tool box corners (eq. 20-21)
    worst_plate_position: list   # where the tool-level worst case occurs
    strut_range: list            # [min, max] strut length over the workspace
    struts_within_limits: bool


def _sign_vectors(n: int = 6) -> np.ndarray:
    return np.array(list(itertools.product((-1.0, 1.0), repeat=n)))


def resolution_at(platform: GoughPlatform, positions: np.ndarray, epsilon_m: float,
                  tool_box: np.ndarray, parts: bool = False):
    """Worst-case resolution at each plate position (null orientation), MoM3 §5.5.

    For the 2^6 strut error vectors dl in {-eps, +eps}^6: dx_h = J_h dl (eq. 1),
    dp_t = dp_h + dr_h x E_hE_t (eq. 5, 13); the maximum over the tool bounding box
    lies on one of its 8 corners (§5.5.2). Returns per position (position, orientation,
    tool) maxima, each of shape (N,), and with ``parts`` also (tilt, twist) maxima.
    """
    n = positions.shape[0]
    rot = np.broadcast_to(np.eye(3), (n, 3, 3))
    jh = np.linalg.inv(platform.inverse_jacobian_batch(positions, rot))      # (N, 6, 6)
    dl = epsilon_m * _sign_vectors(6)                                          # (64, 6)
    dx = np.einsum("nij,sj->nsi", jh, dl)                                      # (N, 64, 6)
    dp, dr = dx[..., :3], dx[..., 3:]
    pos = np.sqrt((dp**2).sum(-1)).max(-1)
    ori = np.sqrt((dr**2).sum(-1)).max(-1)
    corners = np.array(list(itertools.product(*tool_box)))                    # (8, 3)
    # dr x L for every corner, then the worst over (sign vector, corner)
    cross = np.stack([
        dr[..., None, 1] * corners[:, 2] - dr[..., None, 2] * corners[:, 1],
        dr[..., None, 2] * corners[:, 0] - dr[..., None, 0] * corners[:, 2],
        dr[..., None, 0] * corners[:, 1] - dr[..., None, 1] * corners[:, 0]], axis=-1)
    tool = np.sqrt(((dp[..., None, :] + cross) ** 2).sum(-1)).max(axis=(-1, -2))
    if parts:
        tilt = np.sqrt((dr[..., :2] ** 2).sum(-1)).max(-1)
        twist = np.abs(dr[..., 2]).max(-1)
        return pos, ori, tool, tilt, twist
    return pos, ori, tool


def cube_points(center, size: float, points_per_axis: int) -> np.ndarray:
    axes = [np.linspace(c - size / 2.0, c + size / 2.0, points_per_axis) for c in center]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def gough_resolution(platform: GoughPlatform, epsilon_m: float, tool_box, center, size: float,
                     points_per_axis: int = 7) -> ResolutionResult:
    """MoM3 criterion C_opt (eq. 20-21) and its position/orientation parts over the
    workspace cube (sampled ``points_per_axis``^3, corners included)."""
    positions = cube_points(center, size, points_per_axis)
    pos, ori, tool, tilt, twist = resolution_at(platform, positions, epsilon_m, np.asarray(tool_box), parts=True)
    lengths = platform.strut_lengths_batch(positions, np.broadcast_to(np.eye(3), (len(positions), 3, 3)))
    return ResolutionResult(
        position_m=float(pos.max()), orientation_rad=float(ori.max()), tilt_rad=float(tilt.max()),
        twist_rad=float(twist.max()), tool_m=float(tool.max()),
        worst_plate_position=positions[int(np.argmax(tool))].tolist(),
        strut_range=[float(lengths.min()), float(lengths.max())],
        struts_within_limits=bool(platform.within_strut_limits(lengths).all()),
    )


def gough_design_figures(r_base: float, r_plate: float, alpha_base_deg: float, alpha_plate_deg: float,
                         epsilon_m: float, tool_box, positions: np.ndarray, strut_limits, home,
                         plate_line_offset_deg: float = 60.0) -> tuple:
    """A MoM3-parametrised Gough platform (§5.2) judged over plate positions (null
    orientation): (C_opt the worst tool-level resolution (eq. 20-21), the worst position
    resolution, the shortest and longest strut, whether the struts fit their limits).
    The criterion of ``optimize_gough_geometry`` and of design sweeps (design.py)."""
    base, plate = mom3_points(r_base, r_plate, math.radians(alpha_base_deg), math.radians(alpha_plate_deg),
                              math.radians(plate_line_offset_deg))
    platform = GoughPlatform(base, plate, tuple(strut_limits), np.asarray(home, dtype=float))
    lengths = platform.strut_lengths_batch(positions, np.broadcast_to(np.eye(3), (len(positions), 3, 3)))
    pos, _, tool = resolution_at(platform, positions, epsilon_m, np.asarray(tool_box, dtype=float))
    return (float(tool.max()), float(pos.max()), float(lengths.min()), float(lengths.max()),
            bool(platform.within_strut_limits(lengths).all()))


@dataclass
class GoughDesign:
    r_base: float
    r_plate: float
    alpha_base_deg: float
    alpha_plate_deg: float
    criterion_m: float           # C_opt, worst tool-level resolution (no penalty)
    strut_range: list
    struts_within_limits: bool
    evaluations: int


def optimize_gough_geometry(epsilon_m: float, tool_box, center, size: float, strut_limits,
                            bounds=((0.2, 0.6), (0.03, 0.075), (2.0, 60.0), (2.0, 60.0)),
                            points_per_axis: int = 3, seed: int = 1, maxiter: int = 40,
                            popsize: int = 10) -> GoughDesign:
    """Minimise C_opt (MoM3 eq. 20) over P = [r_b, r_tp, alpha_b, alpha_tp] (§5.5.3)
    with scipy's differential evolution, over the workspace cube ``center``/``size``
    (plate-centre positions in the Gough base frame). Designs whose struts leave
    ``strut_limits`` anywhere on the workspace are penalised; the result reports the
    criterion without the penalty and whether the struts fit. Default bounds follow
    §5.6 (r_tp at most 75 mm, no collision with the Delta)."""
    from scipy.optimize import differential_evolution

    center = np.asarray(center, dtype=float)
    lo, hi = strut_limits
    positions = cube_points(center, size, points_per_axis)
    count = [0]

    def criterion(params):
        count[0] += 1
        value, _, shortest, longest, _ = gough_design_figures(*params, epsilon_m, tool_box, positions,
                                                              (lo, hi), center)
        violation = max(0.0, lo - shortest) + max(0.0, longest - hi)
        if not math.isfinite(value):
            return 1.0
        return value + 10.0 * violation * epsilon_m / 1e-3

    res = differential_evolution(criterion, bounds, seed=seed, maxiter=maxiter, popsize=popsize,
                                 tol=1e-8, polish=True)
    rb, rp, ab, ap = res.x
    value, _, shortest, longest, fit = gough_design_figures(rb, rp, ab, ap, epsilon_m, tool_box, positions,
                                                            (lo, hi), center)
    return GoughDesign(float(rb), float(rp), float(ab), float(ap), value, [shortest, longest], fit, count[0])


# ------------------------------------------------ Orthoglide §4.4 sizing
def orthoglide_model(link_length: float, joint_limits=(-math.inf, math.inf)) -> RailMachine:
    """An Orthoglide of parallelogram length L in the frame of the isotropic point."""
    legs = [RailLeg(f"rho{i + 1}", (0.0, 0.0, 0.0), tuple(np.eye(3)[i]), link_length,
                             (0.0, 0.0, 0.0), -1, joint_limits) for i in range(3)]
    return RailMachine("orthoglide", legs, np.zeros(3), POSITION, "three_spheres")


@dataclass
class OrthoglideSizing:
    link_length_m: float          # L of the three parallelograms
    actuator_range_m: float       # stroke of each linear joint over the cube
    joint_limits_m: list          # [rho_min, rho_max] (rho = -L at the isotropic point)
    q1: list                      # cube corner closest to one singularity (x = y = z)
    q2: list                      # opposite corner
    workspace_center: list
    psi_range_on_cube: list       # [min, max] transmission factor found on the cube
    range_ratio: float            # actuator range / cube size


def orthoglide_size(cube_m: float, psi_min: float, psi_max: float, check_points: int = 11) -> OrthoglideSizing:
    """Size an Orthoglide for a prescribed cubic workspace and transmission-factor
    bounds psi_min <= psi_i <= psi_max (Orthoglide §4.4, eq. 11, 15).

    Step 1-2: along the diagonal x = y = z the factors reach their bounds at Q1 (t < 0)
    and Q2 (t > 0); for L = 1 these are found by root finding on psi(t), and since psi
    is scale-free, L = cube / (t2 - t1) makes Q1 Q2 the diagonal of the prescribed
    cube. Step 3: the actuator range is the stroke of rho_i = p_i - sqrt(L^2 - p_j^2 - p_k^2)
    over the cube, monotone in p_i and in |p_j|, |p_k|. The bounds are then checked on a
    grid of the cube (the paper verified the postulate of step 1 numerically too).
    """
    if not (0.0 < psi_min < 1.0 < psi_max):
        raise ValueError(f"psi bounds: need 0 < psi_min < 1 < psi_max, got [{psi_min}, {psi_max}]")
    if not cube_m > 0.0:
        raise FieldError("cube", f"must be > 0 m, got {cube_m}")
    unit = orthoglide_model(1.0)

    def excess(t: float) -> float:
        psi = unit.transmission_factors(np.full(3, t))
        return max(psi[-1] / psi_max, psi_min / psi[0]) - 1.0

    def first_crossing(direction: float) -> float:
        limit = 1.0 / math.sqrt(2.0)          # sqrt(L^2 - 2t^2) vanishes (serial singularity)
        ts = direction * np.linspace(0.0, limit * (1 - 1e-6), 2001)
        vals = np.array([excess(t) for t in ts[1:]])
        k = int(np.argmax(vals > 0.0))
        if vals[k] <= 0.0:
            raise ValueError("transmission bounds never reached along the diagonal")
        return brentq(excess, ts[k], ts[k + 1], xtol=1e-15)

    t2, t1 = first_crossing(1.0), first_crossing(-1.0)
    length = cube_m / (t2 - t1)
    lo_c, hi_c = t1 * length, t2 * length
    # rho over the cube: max at p_i = hi, |p_j| = |p_k| = max|.|; min at p_i = lo, p_j = p_k = 0 (if inside)
    far = max(abs(lo_c), abs(hi_c))
    near = 0.0 if lo_c <= 0.0 <= hi_c else min(abs(lo_c), abs(hi_c))
    rho_max = hi_c - math.sqrt(length**2 - 2.0 * far**2)
    rho_min = lo_c - math.sqrt(length**2 - 2.0 * near**2)
    model = orthoglide_model(length)
    center = (lo_c + hi_c) / 2.0
    psi = model.transmission_factors_batch(cube_points([center] * 3, cube_m, check_points))
    return OrthoglideSizing(
        link_length_m=length, actuator_range_m=rho_max - rho_min, joint_limits_m=[rho_min, rho_max],
        q1=[lo_c] * 3, q2=[hi_c] * 3, workspace_center=[center] * 3,
        psi_range_on_cube=[float(np.nanmin(psi)), float(np.nanmax(psi))],
        range_ratio=(rho_max - rho_min) / cube_m)


# ------------------------------------------------------------ sensor redundancy
def degree_of_sensor_redundancy(c: int, m: int, o: int, d: int) -> int:
    """dosr = C - (M - O + D) (MoM3 §3.1): C independent measures, M the dimension of
    the space the end-effector moves in (O in the "perfect" case, 6 in the
    "imperfect" one: parasitic motions), O its spatiality, D the mechanism's degrees
    of freedom. < 0 under-measured, 0 iso-measured, > 0 over-measured."""
    for name, value in (("C", c), ("M", m), ("O", o), ("D", d)):
        if not (isinstance(value, int) and value >= 0):
            raise FieldError("dosr", f"{name} must be an integer >= 0, got {value!r}")
    if not 1 <= o <= m <= 6:
        raise FieldError("dosr", f"needs 1 <= O <= M <= 6, got O = {o}, M = {m}")
    return c - (m - o + d)


def measurement_verdict(dosr: int) -> str:
    """MoM3 §3.1's three cases."""
    return "under-measured" if dosr < 0 else "iso-measured" if dosr == 0 else "over-measured"


@dataclass(frozen=True)
class SensorRedundancy:
    """One row of :func:`sensor_redundancy`: a sensor set of a machine, its C, and the
    dosr in the perfect (M = O) and imperfect (M = 6) cases."""

    sensors: str
    c: int
    o: int
    d: int
    dosr_perfect: int
    dosr_imperfect: int


GOUGH_STRUTS = 6           # the passive Gough platform's measures (MoM3 §4.2: C = 6)


def sensor_redundancy(n_drives: int, has_metrology: bool, dof: int = 3, spatiality: int = 3) -> list[SensorRedundancy]:
    """The dosr of a machine's sensor sets (MoM3 §3): its drive encoders alone (one
    measure per drive), and where it has the Gough metrology, the six struts alone
    (the loop closed on them, as on MoM3) and both together. D and O are the
    machine's (3 for the planar and translational machines: actuation redundancy adds
    drives, not DOF; 6 for a hexapod, whose struts are its encoders)."""
    sets = [("encoders", n_drives)]
    if has_metrology:
        sets += [("gough struts", GOUGH_STRUTS), ("encoders + gough struts", n_drives + GOUGH_STRUTS)]
    return [SensorRedundancy(name, c, spatiality, dof,
                             degree_of_sensor_redundancy(c, spatiality, spatiality, dof),
                             degree_of_sensor_redundancy(c, 6, spatiality, dof)) for name, c in sets]
