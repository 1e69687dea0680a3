"""Trajectory core (no rclpy): geometric segments, a jerk-limited time law per segment,
sampling, and validation against the machine model before anything moves.

Task coordinates are the machine's (``pkm_kinematics.task_space``): planar (x, y, theta),
a position (x, y, z), or a spatial pose (x, y, z, a, b, c).
Every segment is a path x(u), u in [0, 1], with dx/du and d2x/du2. Its time law u(t)
is Ruckig's time-optimal jerk-limited 1-D profile from rest to rest (exact stop at
every corner) with the path limits derived from the per-axis limits:

    xdot = x' udot,  xddot = x' uddot + x'' udot^2,  xdddot = x' udddot + 3 x'' udot uddot + x''' udot^3

For lines and pure rotations x'' = 0, so |x'_i| udot <= v_i, |x'_i| uddot <= a_i,
|x'_i| udddot <= j_i are exact. For arcs of radius R and angle phi (|x'| = R phi), a
part of the acceleration and jerk budget is kept for the normal terms: the speed is
capped at sqrt(a_n R) (a_n: half the acceleration limit) and the tangential
acceleration and jerk get the other half; the sampled profile is then checked.

Why over 600 lines: the geometric segments, their time law, sampling and the
validation against the machine are one planner; the G-code reader and the program's
chaining live beside it (gcode.py, program.py, plan_chain.py).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from pkm_kinematics.analysis import task_box
from pkm_kinematics.errors import FieldError
from pkm_kinematics.measures import condition_numbers
from pkm_kinematics.validation import finite_floats

from .time_optimal import DriveLimits, DriveModel, drive_excess, drive_rates, jerk_window, smoothed, time_optimal_law


RATE_HZ_RANGE = (1.0, 20000.0)      # a trajectory's sample rate (Hz)


class TrajectoryRejected(ValueError):
    """A planned trajectory violates a limit: names the sample, the limit and by how much."""


@dataclass(frozen=True)
class Limits:
    """Per-axis limits in task coordinates (m or rad, per s, s^2, s^3): one value per
    task coordinate (3 for the planar and translational machines, 6 for a hexapod's
    x, y, z, a, b, c)."""

    velocity: tuple
    acceleration: tuple
    jerk: tuple

    def __post_init__(self):
        axes = len(self.velocity)
        for name in ("velocity", "acceleration", "jerk"):
            values = getattr(self, name)
            if len(values) not in (3, 6) or len(values) != axes or \
                    not all(v > 0.0 and math.isfinite(v) for v in values):
                raise ValueError(f"limits.{name}: expected {axes if axes in (3, 6) else 3} positive finite numbers "
                                 f"(3 or 6 task coordinates, the same for velocity, acceleration and jerk), "
                                 f"got {values!r}")


# ------------------------------------------------------------------ segments
@dataclass(frozen=True)
class Line:
    """Straight line in task space, translation and rotation together (ARCHI's test
    motion: a translation while the nacelle turns from pi/4 to pi/2)."""

    start: tuple
    end: tuple
    speed: float | None = None     # path speed cap of the translation (m/s), e.g. a G-code feed
    blend_tolerance: float | None = None   # its corner's blending (G64 P / G61: 0), None: the plan's own
    line: int | None = field(default=None, compare=False)     # its program line, for a refusal

    def point(self, u):
        if u >= 1.0:
            return list(self.end)              # exactly the target, not a + (b - a)
        return [a + u * (b - a) for a, b in zip(self.start, self.end)]

    def first(self, _u):
        return [b - a for a, b in zip(self.start, self.end)]

    def second(self, _u):
        return [0.0] * len(self.start)

    def radius(self):
        return math.inf


@dataclass(frozen=True)
class Arc:
    """Circular arc in the plane of the task coordinates ``axes`` (x, y by default; a
    G18 arc's (z, x), a G19 arc's (y, z)) about ``center`` (its two coordinates there);
    the other coordinates go linearly from the start's to ``end_rest`` (theta; or z, a
    helix; or z, a, b, c), in their order. ``sweep`` is the signed angle (rad, positive
    from the plane's first axis towards its second)."""

    start: tuple
    center: tuple
    sweep: float
    end_rest: tuple
    speed: float | None = None
    line: int | None = field(default=None, compare=False)
    axes: tuple = (0, 1)

    @property
    def r(self):
        i, j = self.axes
        return math.hypot(self.start[i] - self.center[0], self.start[j] - self.center[1])

    @property
    def phi0(self):
        i, j = self.axes
        return math.atan2(self.start[j] - self.center[1], self.start[i] - self.center[0])

    def _rest(self):
        return [k for k in range(len(self.start)) if k not in self.axes]

    def _compose(self, circle, linear):
        out = [0.0] * len(self.start)
        out[self.axes[0]], out[self.axes[1]] = circle
        for k, v in zip(self._rest(), linear):
            out[k] = v
        return out

    def point(self, u):
        a = self.phi0 + u * self.sweep
        return self._compose((self.center[0] + self.r * math.cos(a), self.center[1] + self.r * math.sin(a)),
                             [self.start[k] + u * (e - self.start[k]) for k, e in zip(self._rest(), self.end_rest)])

    def first(self, u):
        a = self.phi0 + u * self.sweep
        return self._compose((-self.r * self.sweep * math.sin(a), self.r * self.sweep * math.cos(a)),
                             [e - self.start[k] for k, e in zip(self._rest(), self.end_rest)])

    def second(self, u):
        a = self.phi0 + u * self.sweep
        return self._compose((-self.r * self.sweep**2 * math.cos(a), -self.r * self.sweep**2 * math.sin(a)),
                             [0.0] * len(self.end_rest))

    def radius(self):
        return self.r

    @property
    def end(self):
        return tuple(self.point(1.0))


@dataclass(frozen=True)
class Dwell:
    at: tuple
    duration_s: float
    line: int | None = field(default=None, compare=False)
    event: tuple | None = field(default=None, compare=False)    # a program event here (gcode.Move.event)

    @property
    def end(self):
        return self.at


# ------------------------------------------------------------------ time law
@dataclass
class TimedSegment:
    segment: object
    duration_s: float
    profile: Trajectory | object | None   # u(t): Ruckig's 1-D profile or time_optimal.TimedPath; None: a dwell


def time_law(segment, limits: Limits, translation_axes: int = 3) -> TimedSegment:
    """Time-optimal jerk-limited u(t) from rest to rest for one segment (Ruckig).

    ``translation_axes``: how many leading coordinates are a translation (2 for a
    planar machine, whose third coordinate is the angle): a segment's ``speed`` caps
    the norm of their rate."""
    if isinstance(segment, Dwell):
        return TimedSegment(segment, segment.duration_s, None)
    bounds = getattr(segment, "bounds", None)   # a curved path (pivot.PivotLine): its largest |x'|, |x''|
    curvature = None
    if bounds is not None:
        d, curvature = (list(b) for b in bounds())
    else:
        d = [abs(v) for v in segment.first(0.0)]
    if max(d) < 1e-12:                          # a move to where we are (round-off from a goal)
        return TimedSegment(segment, 0.0, None)
    r = segment.radius()
    if math.isfinite(r):
        # an arc's rates in its plane reach R |phi| somewhere on the sweep, not only at u = 0
        for k in segment.axes:
            d[k] = r * abs(segment.sweep)
    inf = math.inf
    vmax = min(v / di if di > 0 else inf for v, di in zip(limits.velocity, d))
    amax = min(a / di if di > 0 else inf for a, di in zip(limits.acceleration, d))
    jmax = min(j / di if di > 0 else inf for j, di in zip(limits.jerk, d))
    speed = getattr(segment, "speed", None)
    if speed is not None:
        if not speed > 0.0:
            raise FieldError("speed", f"must be > 0 m/s, got {speed}")
        norm = segment.tip_length if bounds is not None else math.sqrt(sum(v * v for v in d[:translation_axes]))
        if norm > 0.0:
            vmax = min(vmax, speed / norm)
    if math.isfinite(r):
        # keep half of the budget for the normal terms: centripetal acceleration v^2/R
        # and its jerk v^3/R^2 (+ 3 v a_t / R): v <= sqrt(a R / 2), v <= (j R^2 / 4)^(1/3),
        # a_t <= a / 2 and j_t <= j / 4 - 3 v a_t / R kept positive
        scale = r * abs(segment.sweep)
        a_lin = min(limits.acceleration[k] for k in segment.axes)
        j_lin = min(limits.jerk[k] for k in segment.axes)
        v_cap = min(math.sqrt(0.5 * a_lin * r), (0.25 * j_lin * r * r) ** (1.0 / 3.0))
        a_t = min(0.5 * a_lin, j_lin * r / (12.0 * v_cap))
        vmax = min(vmax, v_cap / scale)
        amax = min(amax, a_t / scale)
        jmax = min(jmax, 0.25 * j_lin / scale)
    if curvature is not None:
        # half of each acceleration budget for x'' udot^2 (as an arc's normal terms), the other half for x' uddot
        vmax = min([vmax] + [math.sqrt(0.5 * a / c) for a, c in zip(limits.acceleration, curvature) if c > 0.0])
        amax = min([amax] + [0.5 * a / di for a, di in zip(limits.acceleration, d) if di > 0.0])
        jmax = min([jmax] + [0.25 * j / di for j, di in zip(limits.jerk, d) if di > 0.0])
    inp = InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [1.0], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [vmax], [amax], [jmax]
    profile = Trajectory(1)
    try:
        result = Ruckig(1).calculate(inp, profile)
    except Exception as exc:                    # RuckigError is not a ValueError
        raise TrajectoryRejected(f"ruckig could not plan the segment: {exc}") from None
    if result not in (Result.Working, Result.Finished):
        raise TrajectoryRejected(f"ruckig could not plan the segment ({result})")
    return TimedSegment(segment, profile.duration, profile)


def sample_segment(timed: TimedSegment, t: float):
    """(x, xdot, xddot) at time t in the segment (clamped to its duration)."""
    seg = timed.segment
    if timed.profile is None:
        x = list(seg.end) if isinstance(seg, Dwell) else seg.point(1.0)
        return x, [0.0] * len(x), [0.0] * len(x)
    if t >= timed.duration_s:                  # at rest exactly on the target
        x = seg.point(1.0)
        return x, [0.0] * len(x), [0.0] * len(x)
    u, ud, udd = (v[0] for v in timed.profile.at_time(max(t, 0.0)))
    x1, x2 = seg.first(u), seg.second(u)
    return (seg.point(u), [a * ud for a in x1], [a * udd + b * ud * ud for a, b in zip(x1, x2)])


@dataclass
class Samples:
    """A sampled trajectory: times (N,), positions, velocities, accelerations (N, 3)."""

    time_s: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    events: list = field(default_factory=list)     # (t_s, line, (name, ((key, value), ...))): the program's events

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1]) if len(self.time_s) else 0.0


def sample_times(duration_s: float, rate_hz: float) -> np.ndarray:
    """A segment's sample times at ``rate_hz``: 0, dt, ..., and its end exactly."""
    n = max(1, math.ceil(duration_s * rate_hz - 1e-9))
    return np.minimum(np.arange(n + 1) / rate_hz, duration_s)


def sampled(timed: TimedSegment, times) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, xdot, xddot) of a timed segment at ``times`` (each (N, dof))."""
    return tuple(np.array(z, dtype=float) for z in zip(*(sample_segment(timed, t) for t in times)))


def segment_law(segment, limits: Limits, translation_axes: int = 3, drives: DriveModel | None = None,
                rate_hz: float = 1000.0) -> TimedSegment:
    """The time law of one segment: Ruckig's jerk-limited one within the task limits
    (time_law); with ``drives``, where that one would take a drive over its velocity,
    acceleration or force limit at one of its samples, the fastest that keeps them all
    (time_optimal.time_optimal_law: slowing down where the machine needs it instead of
    refusing). ValueError where no speed keeps them."""
    timed = time_law(segment, limits, translation_axes)
    if drives is None or timed.profile is None or keeps_drive_limits(timed, drives, rate_hz):
        return timed
    found = "no margin kept them"
    for margin in DRIVE_MARGINS:     # the smoothing's lag can cost a little: a tighter margin until they hold
        try:
            law = time_optimal_law(segment, drives, limits.velocity, limits.acceleration,
                                   getattr(segment, "speed", None), translation_axes, margin=margin)
            if law.duration > drives.max_duration_s:     # before its samples are made (PlanBudget.max_points)
                raise ValueError(f"slowed down for the drives, the move takes {law.duration:.4g} s: over the "
                                 f"{drives.max_duration_s:.4g} s max_points allows")
            law = smoothed(law, jerk_window(segment, drives, law, limits.jerk, drives.jerk))
        except ValueError as exc:
            raise TrajectoryRejected(f"{_where(segment)}{exc}") from None
        candidate = TimedSegment(segment, law.duration, law)
        found = limits_exceeded(candidate, limits, drives, rate_hz)
        if found is None:
            return candidate
    raise TrajectoryRejected(f"{_where(segment)}the drive-limited time law exceeds a limit: {found}")


def keeps_drive_limits(timed: TimedSegment, drives: DriveModel, rate_hz: float) -> bool:
    """Whether a segment's samples keep every drive's velocity, acceleration and force
    (time_optimal.drive_excess) and, with ``drives.jerk``, its jerk (finite differences)."""
    times = sample_times(timed.duration_s, rate_hz)
    x, v, a = sampled(timed, times)
    if drive_excess(drives, x, v, a) is not None:
        return False
    if drives.jerk is None:
        return True
    _, _, qddot = drive_rates(drives.machine, x, v, a)
    return bool(np.all(np.abs(np.diff(qddot, axis=0) / np.diff(times)[:, None]) <= drives.jerk * (1 + JERK_TOLERANCE)))


DRIVE_MARGINS = (0.99, 0.97, 0.93, 0.85, 0.7, 0.5)
JERK_TOLERANCE = 0.02       # jerk by finite differences of the samples' accelerations


def limits_exceeded(timed: TimedSegment, limits: Limits, drives: DriveModel, rate_hz: float) -> str | None:
    """What a drive-limited segment's samples exceed, or None: every drive's velocity,
    acceleration and force (and jerk with ``drives.jerk``), every task axis's velocity,
    acceleration and jerk (finite differences of the sampled accelerations)."""
    times = sample_times(timed.duration_s, rate_hz)
    x, v, a = sampled(timed, times)
    excess = drive_excess(drives, x, v, a)
    if excess is not None:
        return f"sample {excess[0]}: {excess[1]}"
    dt = np.diff(times)[:, None]
    rows = [(np.abs(v), limits.velocity, "velocity"), (np.abs(a), limits.acceleration, "acceleration"),
            (np.abs(np.diff(a, axis=0) / dt), np.array(limits.jerk) * (1 + JERK_TOLERANCE), "jerk")]
    if drives.jerk is not None:
        _, _, qddot = drive_rates(drives.machine, x, v, a)
        rows.append((np.abs(np.diff(qddot, axis=0) / dt), drives.jerk * (1 + JERK_TOLERANCE), "drive jerk"))
    for values, cap, what in rows:
        over = values > np.asarray(cap) * (1 + 1e-9)
        if over.any():
            k, i = np.unravel_index(int(np.argmax(over)), over.shape)
            bound = np.ravel(cap)[min(i, np.size(cap) - 1)]
            return f"sample {k}: {what} {values[k, i]:.4g} on axis {i} over {bound:.4g}"
    return None


def plan(segments, limits: Limits, rate_hz: float = 1000.0, translation_axes: int = 3,
         drives: DriveModel | None = None) -> Samples:
    """Time every segment (exact stop between them; with ``drives``, within the drives'
    limits: segment_law) and sample at ``rate_hz``; the last sample is exactly the end
    of the last segment."""
    if not rate_hz > 0.0:
        raise FieldError("rate_hz", f"must be > 0, got {rate_hz}")
    timed, events, t_event = [], [], 0.0
    for seg in segments:
        ts = segment_law(seg, limits, translation_axes, drives, rate_hz)
        if getattr(seg, "event", None) is not None:        # at its place in time: between the moves around it
            events.append((t_event, seg.line, seg.event))
        if ts.duration_s > 0.0:
            timed.append(ts)
            t_event += ts.duration_s
    if not timed:
        raise TrajectoryRejected("nothing to do: every segment has zero length and duration")
    dt = 1.0 / rate_hz
    times, xs, vs, accs = [], [], [], []
    t0 = 0.0
    for k, ts in enumerate(timed):
        n = max(1, math.ceil(ts.duration_s / dt - 1e-9))
        first = 0 if k == 0 else 1
        for i in range(first, n + 1):
            t = min(i * dt, ts.duration_s)
            x, v, a = sample_segment(ts, t)
            times.append(t0 + t)
            xs.append(x)
            vs.append(v)
            accs.append(a)
        t0 += ts.duration_s
    return Samples(np.array(times), np.array(xs), np.array(vs), np.array(accs), events)


# ----------------------------------------------------------------- the budget
@dataclass(frozen=True)
class PlanBudget:
    """What one plan may cost, decided before it is sampled: its samples (each is a
    message's worth of memory in the planner, the controller and the bag), its
    segments, and the time to blend its corners."""

    max_points: int = 200_000
    max_segments: int = 10_000
    max_planning_s: float = 10.0

    def __post_init__(self):
        for name, lo in (("max_points", 2), ("max_segments", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise FieldError(name, f"must be an integer >= {lo}, got {value!r}")
        if not 0.0 < self.max_planning_s < math.inf:
            raise FieldError("max_planning_s", f"must be in (0, inf) s, got {self.max_planning_s!r}")


def _where(segment) -> str:
    line = getattr(segment, "line", None)
    return f"line {line}: " if line is not None else ""


def check_plan_size(segments, limits: Limits, rate_hz: float, budget: PlanBudget, translation_axes: int = 3,
                    blended: bool = False) -> float:
    """Refuse a plan beyond ``budget`` before a sample is made (TrajectoryRejected,
    naming the segment's line): too many segments; a dwell, or any one segment, longer
    than ``max_points`` samples; or all of them together (each segment is timed, once
    per distinct segment: a repeated program's copies share theirs). A blended plan is
    shorter than its segments end to end, by at most half (each corner overlaps at most
    half of its shorter line), so it is refused here only when half is too long; the
    sampled count is checked after. Returns the end-to-end duration (s)."""
    if len(segments) > budget.max_segments:
        raise TrajectoryRejected(f"{len(segments)} segments exceed max_segments {budget.max_segments}")
    most = budget.max_points / rate_hz                   # seconds of samples the budget allows
    for seg in segments:                                 # dwells first: no timing needed
        if isinstance(seg, Dwell) and not seg.duration_s <= most:
            raise TrajectoryRejected(f"{_where(seg)}a dwell of {seg.duration_s:g} s exceeds max_points "
                                     f"{budget.max_points} ({most:g} s at {rate_hz:g} Hz)")
    durations, total, longest = {}, 0.0, None
    for seg in segments:
        d = durations.get(id(seg))
        if d is None:
            d = durations[id(seg)] = time_law(seg, limits, translation_axes).duration_s
            if not d <= most:
                raise TrajectoryRejected(f"{_where(seg)}one move takes {d:g} s (its feed, or its length): it "
                                         f"exceeds max_points {budget.max_points} ({most:g} s at {rate_hz:g} Hz)")
        total += d
        if longest is None or d > durations[id(longest)]:
            longest = seg
    if not (0.5 if blended else 1.0) * total <= most:
        raise TrajectoryRejected(f"the plan takes {total:g} s{' before blending' if blended else ''} "
                                 f"({len(segments)} segments; the longest, {_where(longest)}{durations[id(longest)]:g} "
                                 f"s): it exceeds max_points {budget.max_points} ({most:g} s at {rate_hz:g} Hz)")
    return total


def check_workspace(segments, box, axes=None) -> None:
    """Refuse a plan whose path leaves the workspace ``box`` ((lower, upper) per task
    axis, analysis.task_box; the axes after it are free), naming the first segment's
    line, before anything is timed or moves: a line's ends (the box is convex), 65
    points of an arc. Blended corners stay within their tolerance of the path; the
    samples are checked again (validate). TrajectoryRejected."""
    lo = np.array([b[0] for b in box])
    hi = np.array([b[1] for b in box])
    size = len(box)
    for seg in segments:
        if isinstance(seg, Dwell):
            continue
        us = (0.0, 1.0) if isinstance(seg, Line) else np.linspace(0.0, 1.0, 65)
        for u in us:
            p = np.asarray(seg.point(u), dtype=float)[:size]
            out = (p < lo - 1e-12) | (p > hi + 1e-12)
            if out.any():
                i = int(np.argmax(out))
                name = axes[i] if axes is not None else f"axis {i}"
                raise TrajectoryRejected(f"{_where(seg)}{name} would reach {p[i]:.6g}, outside the workspace "
                                         f"[{lo[i]:.6g}, {hi[i]:.6g}]")


# ----------------------------------------------------------------- validation
def validate(samples: Samples, machine, joint_velocity_limit: float | None = None,
             joint_acceleration_limit: float | None = None, max_condition: float | None = None,
             legs=None, transmission_bounds=None, task_limits: Limits | None = None, workspace=None,
             drives: DriveModel | None = None) -> None:
    """Every sample reachable, inside the joint limits and the joint velocity and
    acceleration limits (qdot = J xdot, qddot = J xddot + Jdot xdot), inside the task
    ``task_limits`` (velocity and acceleration per axis: a backstop for the planner's
    own bounds), inside the ``workspace`` box (analysis.task_box), and better
    conditioned than ``max_condition``; ``legs`` restricts the conditioning check to a
    sub-machine (e.g. a 3-leg ARCHI sub-machine, ARCHI §3.3); ``transmission_bounds``
    (psi_min, psi_max) checks the Orthoglide's velocity transmission factors (§4.3,
    eq. 11); ``drives`` with a force limit: the drive forces of the dynamic model
    (time_optimal.drive_forces). Vectorised over the samples. Raises TrajectoryRejected naming the first
    offending sample (the earliest in time over all checks), the limit and by how much;
    returns None when accepted."""
    x, v = samples.position, samples.velocity
    if len(x) > 1 and not np.all(np.diff(samples.time_s) > 0.0):
        k = int(np.argmin(np.diff(samples.time_s) > 0.0)) + 1
        raise TrajectoryRejected(f"sample {k}: time does not increase ({samples.time_s[k]:.6f} s)")
    failures = []              # (sample, order, message builder) of every check's first failure

    def first(mask, order, message):
        if mask.any():
            k = int(np.argmax(mask))
            failures.append((k, order, lambda: message(k)))

    def scalar_error(call):
        def message(k):
            try:
                call(k)
            except ValueError as exc:
                return str(exc)
            return "rejected"
        return message

    if workspace is not None:
        lo, hi = (np.array([b[k] for b in workspace]) for k in (0, 1))
        inside = x[:, :len(workspace)]
        out = (inside < lo - 1e-12) | (inside > hi + 1e-12)

        def workspace_message(k):
            i = int(np.argmax(out[k]))
            return f"task axis {i} at {inside[k, i]:.6g} outside the workspace [{lo[i]:.6g}, {hi[i]:.6g}]"
        first(out.any(axis=1), 0, workspace_message)
    q, reachable = machine.inverse_kinematics_batch(x)
    first(~reachable, 0, scalar_error(lambda k: machine.inverse_kinematics(x[k], check_limits=False)))
    first(reachable & ~machine.within_joint_limits(np.where(np.isfinite(q), q, 0.0)), 1,
          scalar_error(lambda k: machine.check_joint_limits(q[k])))
    jac, qdot, qddot = drive_rates(machine, x, v, samples.acceleration)     # qdot = J xdot, qddot = J xddot + ...
    ok = np.isfinite(jac).all(axis=(1, 2))
    if max_condition is not None:
        # the machine's own measure (a hexapod's weighs its rotations by its size)
        cond = machine.condition_number_batch(x) if legs is None else condition_numbers(jac[:, list(legs), :])
        cond = np.where(np.isnan(cond), np.inf, cond)
        name = "machine" if legs is None else "sub-machine J_" + "".join(str(i + 1) for i in legs)
        first(reachable & ~(cond <= max_condition), 2,
              lambda k: f"{name} condition number {cond[k]:.4g} exceeds the bound {max_condition:g} "
                        f"by {cond[k] - max_condition:.4g}")
    if transmission_bounds is not None:
        lo, hi = transmission_bounds
        psi = np.full((len(x), 3), 1.0)
        psi[ok] = 1.0 / np.linalg.svd(jac[ok], compute_uv=False)      # Orthoglide §4.3

        def psi_message(k):
            value = psi[k].min() if psi[k].min() < lo else psi[k].max()
            bound = lo if psi[k].min() < lo else hi
            return f"velocity transmission factor {value:.4g} outside [{lo:g}, {hi:g}] by {abs(value - bound):.4g}"
        first(reachable & ((psi.min(axis=1) < lo) | (psi.max(axis=1) > hi)), 3, psi_message)
    if getattr(machine, "parallel_margin", 0.0) > 0.0:          # Orthoglide §3.3: det A away from 0
        measure = machine.parallel_singularity_measure_batch(x)
        first(reachable & ~(measure > machine.parallel_margin), 3,
              scalar_error(lambda k: machine.check_parallel_singularity(x[k])))
    if task_limits is not None:
        caps = (np.array(task_limits.velocity), np.array(task_limits.acceleration))
        for order, (values, cap, what) in enumerate(((v, caps[0], "velocity"),
                                                     (samples.acceleration, caps[1], "acceleration")), start=6):
            over = np.abs(values) > cap * (1.0 + 1e-9)

            def task_message(k, values=values, cap=cap, what=what, over=over):
                i = int(np.argmax(over[k]))
                return (f"task axis {i} {what} {values[k, i]:.4g} exceeds its limit {cap[i]:g} "
                        f"by {abs(values[k, i]) - cap[i]:.4g}")
            first(over.any(axis=1), order, task_message)
    for order, (limit, values, what, unit) in enumerate(((joint_velocity_limit, qdot, "velocity", "m/s"),
                                                         (joint_acceleration_limit, qddot, "acceleration",
                                                          "m/s^2")), start=4):
        if limit is None:
            continue
        over = np.abs(values) > limit

        def message(k, values=values, limit=limit, what=what, unit=unit, over=over):
            i = int(np.argmax(over[k]))
            return (f"leg {machine.leg_names[i]} {what} {values[k, i]:.4g} {unit} exceeds {limit:g} {unit} "
                    f"by {abs(values[k, i]) - limit:.4g}")
        first(reachable & over.any(axis=1), order, message)
    if drives is not None and drives.limits.force is not None:
        excess = drive_excess(drives, x, v, samples.acceleration)
        if excess is not None:
            failures.append((excess[0], 8, lambda: excess[1]))
    if failures:
        k, _, message = min(failures, key=lambda f: (f[0], f[1]))
        raise TrajectoryRejected(f"sample {k} (t = {samples.time_s[k]:.4f} s, "
                                 f"x = {np.round(x[k], 6).tolist()}): {message()}")


def point_to_point(start, end) -> Line:
    """A move to a pose (or an incremental jog when ``end`` is start + delta)."""
    dof = 6 if len(start) == 6 else 3                # task coordinates: 3, or a spatial pose's 6
    start = finite_floats(start, dof, "start")
    return Line(tuple(start), tuple(finite_floats(end, dof, "end")))


# ------------------------------------------------------------------- blending
def _superposed(timed: list, starts: list, t: float, origin=None):
    """x, xdot, xddot of overlapping rest-to-rest line profiles at time t: the start of
    the first profile plus every profile's displacement so far (``origin`` given: the
    profiles listed are the only ones not yet finished, and it is their start)."""
    x = list(timed[0].segment.start if origin is None else origin)
    v = [0.0] * len(x)
    a = [0.0] * len(x)
    for ts, t0 in zip(timed, starts):
        if ts.profile is None:
            continue
        d = ts.segment.first(0.0)
        if t >= t0 + ts.duration_s:
            u, ud, udd = 1.0, 0.0, 0.0
        elif t <= t0:
            continue
        else:
            u, ud, udd = (w[0] for w in ts.profile.at_time(t - t0))
        for i in range(len(x)):
            x[i] += d[i] * u
            v[i] += d[i] * ud
            a[i] += d[i] * udd
    return x, v, a


def _deviation(p, a, b, c) -> float:
    """Distance from p to the polyline a-b-c (the programmed corner)."""
    def seg(p, s, e):
        d = np.subtract(e, s)
        n2 = float(d @ d)
        w = 0.0 if n2 == 0.0 else min(1.0, max(0.0, float(np.subtract(p, s) @ d) / n2))
        return float(np.linalg.norm(np.subtract(p, np.add(s, w * d))))
    return min(seg(p, a, b), seg(p, b, c))


def plan_blended(lines: list, limits: Limits, tolerance: float, rate_hz: float = 1000.0,
                 translation_axes: int = 3, deadline: float | None = None) -> Samples:
    """Corners blended within a path ``tolerance`` (like G64 P) without exceeding the
    limits. Each line keeps its rest-to-rest Ruckig profile and the next line starts
    before the previous one ends: the commanded motion is the sum of the two profiles
    (superposition blending). The overlap is the largest (found by bisection) for which
    the corner stays within ``tolerance`` of the programmed path and every axis within
    its velocity, acceleration and jerk limits, checked densely over the overlap (the
    profiles are piecewise polynomial) - where LinuxCNC's blending exceeds its
    acceleration limit by 1.9-8.1x (LinuxCNC issue #3773). ``deadline``
    (time.monotonic): a corner reached after it refuses the plan (TrajectoryRejected)."""
    if not all(isinstance(s, Line) for s in lines):
        raise FieldError("plan_blended", "blends straight lines only (arcs and dwells stop exactly)")
    lines = [s for s in lines if max(abs(v) for v in s.first(0.0)) >= 1e-12]
    if not lines:
        raise TrajectoryRejected("nothing to do: every line has zero length")
    if not tolerance >= 0.0:
        raise FieldError("tolerance", f"must be >= 0 m, got {tolerance}")
    timed = [time_law(s, limits, translation_axes) for s in lines]
    caps = [np.array(limits.velocity), np.array(limits.acceleration), np.array(limits.jerk)]
    starts = [0.0]
    for k in range(len(timed) - 1):
        if deadline is not None and time.monotonic() > deadline:
            raise TrajectoryRejected(f"{_where(lines[k])}blending its corner passed the planning time limit "
                                     f"(corner {k + 1} of {len(lines) - 1}): blend fewer corners (G61) or "
                                     f"split the program")
        t_end = starts[k] + timed[k].duration_s
        corner = (lines[k].start, lines[k].end, lines[k + 1].end)
        longest = 0.5 * min(timed[k].duration_s, timed[k + 1].duration_s)
        if k > 0:      # never three profiles at once: line k-1 has ended when k+1 starts
            longest = min(longest, max(0.0, t_end - (starts[k - 1] + timed[k - 1].duration_s)))

        pair = timed[k:k + 2]

        def acceptable(overlap, points=61):
            t1 = t_end - overlap
            h = 1e-6
            window = [starts[k], t1]
            for t in np.linspace(t1, t_end, points):
                x, v, a = _superposed(pair, window, t, lines[k].start)
                if _deviation(x[:translation_axes], *[c[:translation_axes] for c in corner]) > 0.99 * tolerance:
                    return False
                a_minus = _superposed(pair, window, t - h, lines[k].start)[2]
                a_plus = _superposed(pair, window, t + h, lines[k].start)[2]
                jerk = (np.array(a_plus) - np.array(a_minus)) / (2 * h)
                for value, cap in zip((np.abs(v), np.abs(a), np.abs(jerk)), caps):
                    if np.any(value > cap * (1 + 1e-9)):
                        return False
            return True

        lo, hi = 0.0, longest
        if tolerance > 0.0 and acceptable(hi):
            lo = hi
        elif tolerance > 0.0:
            for _ in range(10):                 # 1/1000 of the longest overlap
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if acceptable(mid) else (lo, mid)
        # the bisection checked 61 points; the chosen overlap is verified at one point
        # per 0.1 ms (jerk phases are ~1 ms), and shrunk until it passes
        for _ in range(8):
            if lo <= 0.0 or acceptable(lo, points=max(61, int(lo / 1e-4) + 1)):
                break
            lo *= 0.5
        else:
            lo = 0.0
        starts.append(t_end - lo)
    total = starts[-1] + timed[-1].duration_s
    n = max(1, math.ceil(total * rate_hz - 1e-9))
    times = np.minimum(np.arange(n + 1) / rate_hz, total)
    ends = [t0 + ts.duration_s for t0, ts in zip(starts, timed)]
    xs, vs, accs = [], [], []
    first = 0
    for t in times:     # only the profiles still running contribute beyond their start point
        while first < len(timed) - 1 and ends[first] <= t:
            first += 1
        active = [i for i in range(first, min(first + 2, len(timed)))]
        x, v, a = _superposed([timed[i] for i in active], [starts[i] for i in active], t, lines[first].start)
        xs.append(x)
        vs.append(v)
        accs.append(a)
    xs = np.array(xs)
    xs[-1] = lines[-1].end
    return Samples(times, xs, np.array(vs), np.array(accs))


def plan_with_blending(segments, limits: Limits, blend_tolerance: float, rate_hz: float = 1000.0,
                       translation_axes: int = 3, deadline: float | None = None,
                       drives: DriveModel | None = None) -> Samples:
    """Runs of consecutive lines with the same tolerance are blended within it: a line's
    own ``blend_tolerance`` (G64 P, G61: 0) or else ``blend_tolerance``; arcs, dwells,
    the corners of lines under 0 and the corners where the tolerance changes stop
    exactly. The pieces are joined in time at rest, so the limits hold across the joins.
    With ``drives`` every piece keeps the drives' limits (plan); a blended run that would
    exceed one stops exactly at its corners instead."""
    def blended(run):
        part = plan_blended(run, limits, tolerance(run[0]), rate_hz, translation_axes, deadline)
        if drives is not None and drive_excess(drives, part.position, part.velocity, part.acceleration) is not None:
            return plan(run, limits, rate_hz, translation_axes, drives)
        return part

    def tolerance(seg) -> float:
        own = seg.blend_tolerance if isinstance(seg, Line) else None
        return blend_tolerance if own is None else own
    if all(tolerance(seg) <= 0.0 for seg in segments if isinstance(seg, Line)):
        return plan(segments, limits, rate_hz, translation_axes, drives)
    groups, run = [], []
    for seg in segments:
        if isinstance(seg, Line) and (not run or tolerance(seg) == tolerance(run[0])):
            run.append(seg)
            continue
        if run:
            groups.append(("lines", run))
            run = []
        if isinstance(seg, Line):
            run.append(seg)
        else:
            groups.append(("other", [seg]))
    if run:
        groups.append(("lines", run))
    parts = [blended(g) if kind == "lines" and tolerance(g[0]) > 0.0 else plan(g, limits, rate_hz, translation_axes,
                                                                                  drives)
             for kind, g in groups]
    t0, out, events = 0.0, [], []
    for k, part in enumerate(parts):
        skip = 0 if k == 0 else 1            # the first sample repeats the previous end
        out.append((part.time_s[skip:] + t0, part.position[skip:], part.velocity[skip:], part.acceleration[skip:]))
        events += [(t + t0, line, event) for t, line, event in part.events]
        t0 += part.duration_s
    return Samples(*(np.concatenate([o[i] for o in out]) for i in range(4)), events)


def plan_validated(segments, machine, limits: Limits, rate_hz: float = 1000.0, blend_tolerance: float = 0.0,
                   joint_velocity_limit: float | None = None, joint_acceleration_limit: float | None = None,
                   max_condition: float | None = None, budget: PlanBudget | None = None,
                   drive_force_limit: float | None = None, dynamics=None,
                   joint_jerk_limit: float | None = None) -> Samples:
    """What trajectory_node publishes: the segments planned (with corner blending) and
    sampled, then every sample checked against ``machine`` (:func:`validate`). With a
    ``budget`` its size is checked before anything is sampled (check_plan_size) and
    blending stops at its planning time. Raises TrajectoryRejected (or ValueError)
    naming the sample (or line) and the limit. Where the joint velocity and acceleration
    limits (and ``drive_force_limit``, N, with the machine's ``dynamics``) would be
    exceeded the motion slows down (segment_law) rather than being refused, within
    ``joint_jerk_limit`` too where given (the task axes' jerk always)."""
    if len(limits.velocity) != machine.task_space.dof:
        space = machine.task_space
        raise ValueError(f"limits: {len(limits.velocity)} values per limit (max_velocity, max_acceleration, "
                         f"max_jerk) for {machine.name}'s {space.dof} task axes ({', '.join(space.axes)}): give one "
                         "per axis")
    axes = machine.task_space.translation_axes
    drives = None
    if joint_velocity_limit is not None and joint_acceleration_limit is not None:
        longest = budget.max_points / rate_hz if budget is not None else math.inf
        drives = DriveModel(machine, DriveLimits(joint_velocity_limit, joint_acceleration_limit, drive_force_limit),
                            dynamics, joint_jerk_limit, longest)
    box = task_box(machine)
    check_workspace(segments, box, machine.task_space.axes)
    deadline = None
    if budget is not None:
        blended = any(isinstance(seg, Line) and (blend_tolerance if seg.blend_tolerance is None
                                                 else seg.blend_tolerance) > 0.0 for seg in segments)
        check_plan_size(segments, limits, rate_hz, budget, axes, blended)
        deadline = time.monotonic() + budget.max_planning_s
    samples = plan_with_blending(segments, limits, blend_tolerance, rate_hz, translation_axes=axes, deadline=deadline,
                                 drives=drives)
    if budget is not None and len(samples.time_s) > budget.max_points:
        raise TrajectoryRejected(f"{len(samples.time_s)} points exceed max_points {budget.max_points} "
                                 f"({samples.duration_s:.1f} s at {rate_hz:g} Hz)")
    validate(samples, machine, joint_velocity_limit, joint_acceleration_limit, max_condition,
             transmission_bounds=getattr(machine, "transmission_bounds", None), task_limits=limits, workspace=box,
             drives=drives)
    return samples
