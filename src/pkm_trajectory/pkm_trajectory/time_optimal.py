"""The time law that keeps every drive within its limits (no rclpy): the speed along a
segment's path chosen so that no drive exceeds its velocity, acceleration or force
limit, no task axis its velocity or acceleration limit and the translation not its
programmed feed, as fast as these allow.

A path x(s), s in [0, 1], moved with s(t): with x' = dx/ds, x'' = d2x/ds2,

    xdot = x' sd,   xddot = x' sdd + x'' sd^2                  (chain rule)
    qdot = J x' sd, qddot = J x' sdd + (J x'' + (dJ/ds) x') sd^2   (q' = J x', J = machine.task_jacobian)
    f = P W,  W = A(x) twistdot + H(x, twist)                   (the dynamic model's inverse dynamics)

Every constraint is linear in (sdd, sd^2) except viscous friction, linear in sd: it is
bounded by its value at the largest sd the velocity limits allow (conservative). The
drive forces f are the minimum 2-norm distribution of W (ARCHI §4.4.1, the
pseudo-inverse); a controller distributing by the infinity norm needs at most these
(its forces have the least largest force of all distributions).

The time-optimal s(t) under such constraints is TOPP-RA's (Pham & Pham, "A new approach
to time-optimal path parameterization based on reachability analysis", IEEE T-RO
2018), computed by ``toppra`` on a grid of the path; its sd^2 is linear in s between
grid points (constant sdd). Its acceleration is piecewise constant; :func:`smoothed`
averages its velocity profile over the window :func:`jerk_window` finds, which ramps
those steps within every task axis's (and drive's) jerk limit, at the price of the
window (planner.segment_law checks the samples and plans at a tighter margin if the
averaging's lag took one over a limit). planner.py uses this law only where Ruckig's
jerk-limited Cartesian one would exceed a drive's limit.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from pkm_kinematics.errors import FieldError
from pkm_kinematics.task_space import SPATIAL, task_twists

__all__ = ["DriveLimits", "DriveModel", "SmoothedPath", "TimedPath", "drive_excess", "drive_forces", "drive_rates",
           "jerk_window", "smoothed", "time_optimal_law"]

MARGIN = 0.99           # plan at 99 % of every limit: the samples between grid points stay inside
GRID_POINTS = 201       # grid of a segment's path (TOPP-RA's stages + 1)
DERIVATIVE_STEP = 1e-6  # ds of the central difference of J along the path




@dataclass(frozen=True)
class DriveLimits:
    """Every drive's limits: velocity (m/s or rad/s), acceleration (m/s^2 ...), force
    (N or N m; None: no force limit). One value for all drives or one per drive."""

    velocity: float | tuple
    acceleration: float | tuple
    force: float | tuple | None = None

    def __post_init__(self):
        for name in ("velocity", "acceleration", "force"):
            value = getattr(self, name)
            if value is None and name == "force":
                continue
            values = np.atleast_1d(np.asarray(value, dtype=float))
            if not (values.size and np.all(values > 0.0) and np.all(np.isfinite(values))):
                raise FieldError(f"drive_limits.{name}", f"must be positive finite numbers, got {value!r}")

    def per_drive(self, name: str, n: int) -> np.ndarray | None:
        value = getattr(self, name)
        if value is None:
            return None
        values = np.broadcast_to(np.asarray(value, dtype=float), (n,)) if np.ndim(value) == 0 else \
            np.asarray(value, dtype=float)
        if values.shape != (n,):
            raise FieldError(f"drive_limits.{name}", f"needs 1 or {n} values (one per drive), got {value!r}")
        return values


@dataclass(frozen=True)
class DriveModel:
    """What the drive-limited time law needs of a machine: its kinematic model, its
    dynamic model (``pkm_kinematics.dynamics.dynamic_model``; None: no force limit can
    be kept) and the drives' limits."""

    machine: object
    limits: DriveLimits
    dynamics: object = None
    jerk: float | None = None       # every drive's jerk limit (m/s^3 ...; None: the task axes' jerk only)
    max_duration_s: float = math.inf    # a slowed-down move longer than this is refused (the plan's budget)

    def __post_init__(self):
        if self.limits.force is not None and self.dynamics is None:
            raise FieldError("drive_limits.force", "a force limit needs the machine's dynamic model "
                                                   "(its 'dynamics' section)")


def path_derivatives(segment, ss) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, x', x'') of a segment (planner.Line, Arc, ...) at the path parameters ``ss``."""
    return (np.array([segment.point(s) for s in ss], dtype=float),
            np.array([segment.first(s) for s in ss], dtype=float),
            np.array([segment.second(s) for s in ss], dtype=float))


def drive_rates(machine, x, v, a) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(J, qdot, qddot) of samples (x, xdot = v, xddot = a), each (N, ...): qdot = J xdot,
    qddot = J xddot + Jdot xdot, Jdot xdot by a central difference of J along xdot;
    J = 0 where a sample is out of reach (the caller refuses those)."""
    h = DERIVATIVE_STEP
    x, v, a = (np.asarray(z, dtype=float) for z in (x, v, a))
    jac = machine.task_jacobian_batch(x)
    jac0 = np.where(np.isfinite(jac), jac, 0.0)
    with np.errstate(invalid="ignore"):
        jdot = (machine.task_jacobian_batch(x + h * v) - machine.task_jacobian_batch(x - h * v)) / (2.0 * h)
    qdot = np.einsum("nij,nj->ni", jac0, v)
    qddot = np.einsum("nij,nj->ni", jac0, a) + np.einsum("nij,nj->ni", np.where(np.isfinite(jdot), jdot, 0.0), v)
    return jac, qdot, qddot


def drive_excess(model: DriveModel, x, v, a) -> tuple[int, str] | None:
    """The first sample (index) where a drive exceeds its velocity, acceleration or
    force limit (or the pose is out of reach), and what it exceeds by; None when every
    sample keeps every limit."""
    machine = model.machine
    n = machine.n_legs
    jac, qdot, qddot = drive_rates(machine, x, v, a)
    found = []
    reach = np.isfinite(jac).all(axis=(1, 2))
    if not reach.all():
        found.append((int(np.argmin(reach)), "out of the machine's reach"))
    for values, name, what in ((qdot, "velocity", "velocity"), (qddot, "acceleration", "acceleration")):
        cap = model.limits.per_drive(name, n)
        over = np.abs(values) > cap
        if over.any():
            k = int(np.argmax(over.any(axis=1)))
            i = int(np.argmax(np.abs(values[k]) - cap))
            found.append((k, f"leg {machine.leg_names[i]} {what} {values[k, i]:.4g} exceeds {cap[i]:g} "
                             f"by {abs(values[k, i]) - cap[i]:.4g}"))
    cap = model.limits.per_drive("force", n)
    if cap is not None:
        for k, sample in enumerate(zip(x, v, a)):
            if found and k >= min(found)[0]:
                break
            forces = drive_forces(model, *sample)
            if np.any(np.abs(forces) > cap):
                i = int(np.argmax(np.abs(forces) - cap))
                found.append((k, f"leg {machine.leg_names[i]} force {forces[i]:.4g} exceeds {cap[i]:g} "
                                 f"by {abs(forces[i]) - cap[i]:.4g}"))
                break
    return min(found) if found else None


def _wrench_rows(machine, x) -> np.ndarray:
    """J_m at x, the map of the dynamic model's twist: W = J_m^T f."""
    return machine.jacobian(x) if machine.task_space is SPATIAL else machine.task_jacobian_batch([x])[0]


def drive_forces(model: DriveModel, x, v, a) -> np.ndarray:
    """The drive forces (n,) that move the platform along (x, xdot = v, xddot = a): the
    inverse dynamics' wrench distributed by the pseudo-inverse (module doc)."""
    space = model.machine.task_space
    twist, twist_dot = task_twists(space, np.asarray(x, dtype=float), list(v), list(a))
    wrench = np.asarray(model.dynamics.inverse_dynamics(x, twist, twist_dot), dtype=float)
    return np.linalg.pinv(_wrench_rows(model.machine, x).T) @ wrench


def force_terms(model: DriveModel, x, x1, x2) -> tuple[np.ndarray, ...]:
    """f = a sdd + b sd^2 + c + d sd along the path (each (N, n)): the forces are exactly
    linear in sdd and quadratic in sd (Coriolis, the rotation rates' own terms) plus
    viscous friction (d), so four evaluations give them."""
    out = []
    for xi, p1, p2 in zip(x, x1, x2):
        at = [drive_forces(model, xi, sd * p1, sdd * p1 + sd * sd * p2)
              for sdd, sd in ((0, 0), (1, 0), (0, 1), (0, -1))]
        c = at[0]
        out.append((at[1] - c, 0.5 * (at[2] + at[3]) - c, c, 0.5 * (at[2] - at[3])))
    return tuple(np.array(v) for v in zip(*out))


@functools.cache
def _toppra():
    """toppra and the two classes it is given, imported at the first drive-limited law
    (0.5 s of imports: not at every planner's start)."""
    import toppra
    import toppra.algorithm
    import toppra.constraint
    from toppra.interpolator import AbstractGeometricPath
    toppra.setup_logging("WARNING")

    class Path(AbstractGeometricPath):
        """The path interval toppra checks the grid against (the constraint has the rest)."""

        def __init__(self, dof: int):
            self._dof = dof

        def __call__(self, path_positions, order=0):
            raise NotImplementedError("the time law samples the segment itself")

        @property
        def dof(self):
            return self._dof

        @property
        def path_interval(self):
            return np.array([0.0, 1.0])

    class Bounds(toppra.constraint.LinearConstraint):
        """Rows r(s) = a u + b x + c normalised so that each must stay in [-1, 1], and an
        upper bound on x = sd^2 (toppra's canonical linear form)."""

        def __init__(self, a, b, c, x_upper):
            super().__init__()
            self.a, self.b, self.c, self.x_upper = a, b, c, x_upper
            self.identical = True
            self.discretization_type = toppra.constraint.DiscretizationType.Interpolation

        def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
            m = self.a.shape[1]
            f = np.vstack((np.eye(m), -np.eye(m)))
            xbound = np.column_stack((np.zeros(len(gridpoints)), self.x_upper))
            return self.a, self.b, self.c, f, np.ones(2 * m), None, xbound

    return toppra.algorithm.TOPPRA, Path, Bounds


@dataclass
class TimedPath:
    """s(t) through the grid: sd at each grid point, constant sdd between them."""

    grid: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray
    times: np.ndarray          # the time at each grid point

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def at_time(self, t: float):
        """([s], [sd], [sdd]) at time t: the shape of ruckig's Trajectory.at_time."""
        if t >= self.times[-1]:
            return [1.0], [0.0], [0.0]
        i = max(0, min(int(np.searchsorted(self.times, t, side="right")) - 1, len(self.sdd) - 1))
        tau = t - self.times[i]
        u = float(self.sdd[i])
        return ([min(1.0, float(self.grid[i] + self.sd[i] * tau + 0.5 * u * tau * tau))],
                [max(0.0, float(self.sd[i] + u * tau))], [u])


@dataclass
class SmoothedPath:
    """s(t) on a fine time grid (``FINE_STEP_S``), linear between its points: TOPP-RA's
    velocity profile averaged over a window (:func:`smoothed`)."""

    times: np.ndarray
    s: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def at_time(self, t: float):
        if t >= self.times[-1]:
            return [1.0], [0.0], [0.0]
        return tuple([float(np.interp(t, self.times, v))] for v in (self.s, self.sd, self.sdd))


FINE_STEP_S = 1e-4      # the smoothed law's time grid
MAX_FINE_POINTS = 400_000   # and its size at most (a coarser grid for a move over 40 s)


def smoothed(law: TimedPath, window_s: float) -> SmoothedPath:
    """The velocity profile sd(t) averaged over the last ``window_s`` (a moving average:
    the FIR filter of jerk-limited CNC profiles, Biagiotti & Melchiorri, "Trajectory
    Planning for Automatic Machines and Robots", 2008, §4.4). It keeps the distance (the
    area under sd), lasts ``window_s`` longer, and turns the time-optimal law's steps of
    sdd into ramps: |sddd| <= (largest change of sdd) / window_s."""
    step = max(FINE_STEP_S, (law.duration + window_s) / MAX_FINE_POINTS)     # memory bounded on long moves
    m = max(1, round(window_s / step))
    times = np.arange(math.ceil(law.duration / step) + m + 1) * step
    i = np.clip(np.searchsorted(law.times, times, side="right") - 1, 0, len(law.sdd) - 1)
    tau = np.clip(times, 0.0, law.duration) - law.times[i]
    sd = np.where(times < law.duration, law.sd[i] + law.sdd[i] * tau, 0.0)
    total = np.concatenate(([0.0], np.cumsum(sd)))
    k = np.arange(len(times))
    sd_f = (total[k + 1] - total[np.maximum(0, k + 1 - m)]) / m          # the mean of the last m samples
    s_f = np.concatenate(([0.0], np.cumsum(0.5 * (sd_f[1:] + sd_f[:-1]) * step)))
    scale = 1.0 / s_f[-1]                   # the distance exactly 1 (the sums' round-off)
    sdd_f = np.gradient(sd_f, step)
    return SmoothedPath(times, np.minimum(s_f * scale, 1.0), sd_f * scale, sdd_f * scale)


def jerk_window(segment, model: DriveModel, law: TimedPath, jerk, drive_jerk=None) -> float:
    """The averaging window that brings every task axis's jerk (and with ``drive_jerk``
    every drive's) within its limit: each one's acceleration changes by at most its
    range over the time-optimal law, spread over the window."""
    x, x1, x2 = path_derivatives(segment, law.grid)
    sdd = np.concatenate((law.sdd, law.sdd[-1:]))
    sdd_before = np.concatenate((law.sdd[:1], law.sdd))
    rows = [(x1, x2, np.asarray(jerk, dtype=float))]
    if drive_jerk is not None:
        _, q1, q2 = drive_rates(model.machine, x, x1, x2)
        rows.append((q1, q2, np.full(model.machine.n_legs, float(drive_jerk))))
    window = 0.0
    for d1, d2, cap in rows:
        acc = np.vstack([d1 * u[:, None] + d2 * (law.sd ** 2)[:, None] for u in (sdd, sdd_before)])
        window = max(window, float(np.max(np.ptp(acc, axis=0) / cap)))
    return window


def time_optimal_law(segment, model: DriveModel, velocity, acceleration, speed: float | None = None,
                     translation_axes: int = 3, grid_points: int = GRID_POINTS, margin: float = MARGIN) -> TimedPath:
    """The fastest s(t) from rest to rest along ``segment`` within the task axes'
    ``velocity`` and ``acceleration`` limits, the translation's ``speed`` (a feed, m/s,
    or None) and every drive's limits (``model``), at ``margin`` of each. ValueError
    naming the place on the path where no speed is feasible."""
    ss = np.linspace(0.0, 1.0, grid_points)
    x, x1, x2 = path_derivatives(segment, ss)
    machine = model.machine
    n = machine.n_legs
    jac, q1, q2 = drive_rates(machine, x, x1, x2)     # q' = J x', q'' = J x'' + (dJ/ds) x': the same law in s
    reach = np.isfinite(jac).all(axis=(1, 2)) & np.isfinite(q2).all(axis=1)
    if not reach.all():
        k = int(np.argmin(reach))
        raise ValueError(f"the path leaves the machine's reach at s = {ss[k]:.3f}, x = {np.round(x[k], 6).tolist()}")
    vel_q, acc_q = (model.limits.per_drive(name, n) * margin for name in ("velocity", "acceleration"))
    task_v = np.asarray(velocity, dtype=float) * margin
    task_a = np.asarray(acceleration, dtype=float) * margin
    with np.errstate(divide="ignore"):
        rate = np.hstack((np.abs(x1) / task_v, np.abs(q1) / vel_q))             # per unit sd
        if speed is not None:       # the feed: of the translation, or of the tip turned about (pivot.PivotLine)
            length = getattr(segment, "tip_length", None)
            feed = np.linalg.norm(x1[:, :translation_axes], axis=1, keepdims=True) if length is None else \
                np.full((len(ss), 1), length)
            rate = np.hstack((rate, feed / (speed * margin)))
        x_upper = 1.0 / np.max(rate, axis=1) ** 2
    x_upper = np.minimum(x_upper, 1e12)                # a path of zero length moves in no time
    a = np.hstack((x1 / task_a, q1 / acc_q))
    b = np.hstack((x2 / task_a, q2 / acc_q))
    c = np.zeros_like(a)
    force = model.limits.per_drive("force", n)
    if force is not None:
        fa, fb, fc, fd = force_terms(model, x, x1, x2)
        room = force * margin - np.abs(fd) * np.sqrt(x_upper)[:, None]      # friction at the largest speed
        if np.any(room <= np.abs(fc)):
            k, i = np.unravel_index(int(np.argmax(np.abs(fc) - room)), fc.shape)
            raise ValueError(f"leg {machine.leg_names[i]} cannot hold the platform at s = {ss[k]:.3f}, x = "
                             f"{np.round(x[k], 6).tolist()}: it needs {abs(fc[k, i]):.4g} of its {force[i]:g} "
                             "force limit at rest")
        a, b, c = np.hstack((a, fa / room)), np.hstack((b, fb / room)), np.hstack((c, fc / room))
    topp, path, bounds = _toppra()
    algo = topp([bounds(a, b, c, x_upper)], path(x.shape[1]), gridpoints=ss,
                                   solver_wrapper="seidel")
    sdd, sd, _, _ = algo.compute_parameterization(0.0, 0.0, return_data=True)
    if sd is None or not np.all(np.isfinite(sd)):
        bad = int(np.argmax(~np.isfinite(sd))) if sd is not None else 0
        raise ValueError(f"no speed keeps every limit near s = {ss[bad]:.3f}, x = {np.round(x[bad], 6).tolist()} "
                         f"(toppra: {algo.problem_data.return_code})")
    sd = np.sqrt(np.maximum(np.asarray(sd, dtype=float) ** 2, 0.0))
    ds = np.diff(ss)
    dt = 2.0 * ds / np.maximum(sd[:-1] + sd[1:], 1e-300)
    if not np.all(np.isfinite(dt)) or math.isinf(float(dt.sum())):
        raise ValueError("the time-optimal speed is zero inside the path")
    sdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2.0 * ds)
    return TimedPath(ss, sd, sdd, np.concatenate(([0.0], np.cumsum(dt))))
