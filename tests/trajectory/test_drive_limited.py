"""The drive-limited time law (planner.segment_law, time_optimal): paths today's
Cartesian plan takes over a drive's limit are slowed down instead of refused; every
drive keeps its velocity, acceleration and force limit at every sample, checked from
the sampled poses alone (inverse kinematics, finite differences in time); the duration
is within a few per cent of the optimum of an independent discretisation (forward and
backward passes in the phase plane on a grid 10x finer, from inverse kinematics)."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.dynamics import dynamic_model
from pkm_kinematics.task_space import task_twists
from pkm_trajectory.planner import Line, Limits, TrajectoryRejected, plan, plan_validated, validate
from pkm_trajectory.program import gcode_segments
from pkm_trajectory.time_optimal import DriveLimits, DriveModel

HEXAPOD_LIMITS = Limits((0.1,) * 3 + (0.5,) * 3, (1.0,) * 3 + (5.0,) * 3, (40.0,) * 3 + (200.0,) * 3)
ARCHI_LIMITS = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))


@pytest.fixture(scope="module")
def hexapod():
    return load_machine("genhexkins")


@pytest.fixture(scope="module")
def archi():
    return load_machine("archi")


def tilt(machine):
    """A hexapod's tilt with a translation: 8 deg about x, -6 deg about y, 30 mm in x."""
    home = np.array(machine.home, dtype=float)
    end = home + [0.03, 0.0, 0.0, math.radians(8.0), math.radians(-6.0), 0.0]
    return Line(tuple(home), tuple(end))


def drive_motion(machine, samples):
    """Drive positions by inverse kinematics of the sampled poses, their velocities and
    accelerations by central differences in time (independent of the planner's rates)."""
    q, ok = machine.inverse_kinematics_batch(samples.position)
    assert ok.all()
    t = samples.time_s
    return q, np.gradient(q, t, axis=0, edge_order=2), np.gradient(np.gradient(q, t, axis=0), t, axis=0)


def forces_from_poses(config, samples):
    """Drive forces of the dynamic model at each sample, with the task rates from
    finite differences of the sampled poses (least squares J_m^T f = W: the 2-norm)."""
    machine, dynamics = config.model, dynamic_model(config)
    t, x = samples.time_s, samples.position
    v = np.gradient(x, t, axis=0, edge_order=2)
    a = np.gradient(v, t, axis=0)
    out = []
    for xi, vi, ai in zip(x, v, a):
        twist, twist_dot = task_twists(machine.task_space, xi, list(vi), list(ai))
        wrench = dynamics.inverse_dynamics(xi, twist, twist_dot)
        rows = machine.jacobian(xi) if machine.task_space.name == "spatial" else machine.task_jacobian_batch([xi])[0]
        out.append(np.linalg.lstsq(rows.T, wrench, rcond=None)[0])
    return np.array(out)


def reference_duration(machine, segment, task_limits: Limits, v_q: float, a_q: float, n: int = 2001) -> float:
    """The time-optimal duration by an independent discretisation: q(s) by inverse
    kinematics and x(s) on a fine grid, their s-derivatives by finite differences, the
    largest sd^2 each grid point allows (velocity limits, and acceleration rows
    |y' sdd + y'' sd^2| <= A solvable for some sdd), then a forward pass at the largest
    sdd and a backward pass at the largest deceleration (Bobrow's numerical integration
    on a grid)."""
    ss = np.linspace(0.0, 1.0, n)
    ds = ss[1] - ss[0]
    x = np.array([segment.point(s) for s in ss])
    q, ok = machine.inverse_kinematics_batch(x)
    assert ok.all()
    d1 = [np.gradient(y, ds, axis=0, edge_order=2) for y in (x, q)]
    d2 = [np.gradient(y, ds, axis=0, edge_order=2) for y in d1]
    y1, y2 = np.hstack(d1), np.hstack(d2)
    vmax = np.concatenate((task_limits.velocity, [v_q] * q.shape[1]))
    amax = np.concatenate((task_limits.acceleration, [a_q] * q.shape[1]))

    def u_range(k, xk):
        lo, hi = -np.inf, np.inf
        for a, b, cap in zip(y1[k], y2[k], amax):
            if abs(a) < 1e-12:
                if abs(b * xk) > cap:
                    return None
                continue
            u1, u2 = (-cap - b * xk) / a, (cap - b * xk) / a
            lo, hi = max(lo, min(u1, u2)), min(hi, max(u1, u2))
        return (lo, hi) if lo <= hi else None

    mvc = np.empty(n)
    for k in range(n):
        with np.errstate(divide="ignore"):
            top = float(np.min((vmax / np.abs(y1[k])) ** 2))
        lo, hi = 0.0, min(top, 1e6)
        if u_range(k, hi) is not None:
            mvc[k] = hi
            continue
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if u_range(k, mid) is not None else (lo, mid)
        mvc[k] = lo
    xs = np.minimum(mvc, 0.0)
    for k in range(n - 1):                         # forward: the largest acceleration
        r = u_range(k, xs[k])
        xs[k + 1] = min(mvc[k + 1], xs[k] + 2.0 * ds * r[1]) if r else 0.0
    xs[-1] = 0.0
    for k in range(n - 1, 0, -1):                  # backward: the largest deceleration
        r = u_range(k, xs[k])
        xs[k - 1] = min(xs[k - 1], xs[k] - 2.0 * ds * r[0]) if r else xs[k - 1]
    sd = np.sqrt(np.maximum(xs, 0.0))
    return float(np.sum(2.0 * ds / (sd[:-1] + sd[1:])))


def test_hexapod_tilt_refused_today_slowed_down_now_within_every_drive_limit(hexapod):
    machine = hexapod.model
    segment = tilt(machine)
    v_q, a_q = 0.02, 0.2
    cartesian = plan([segment], HEXAPOD_LIMITS)
    with pytest.raises(TrajectoryRejected, match="acceleration .* exceeds 0.2"):
        validate(cartesian, machine, v_q, a_q)
    samples = plan_validated([segment], machine, HEXAPOD_LIMITS, 1000.0, 0.0, v_q, a_q)
    _, qdot, qddot = drive_motion(machine, samples)
    peak_v, peak_a = np.abs(qdot).max(), np.abs(qddot[2:-2]).max()
    assert peak_v <= v_q * 1.001 and peak_a <= a_q * 1.01, (peak_v, peak_a)
    assert peak_v >= 0.97 * v_q or peak_a >= 0.97 * a_q, (peak_v, peak_a)     # a limit is used: not just slow
    assert np.allclose(samples.position[-1], segment.end, atol=1e-12)
    reference = reference_duration(machine, segment, HEXAPOD_LIMITS, v_q, a_q)
    assert samples.duration_s > cartesian.duration_s
    assert abs(samples.duration_s / reference - 1.0) < 0.03, (samples.duration_s, reference)


def test_hexapod_force_limit_kept_from_the_dynamic_model(hexapod):
    machine = hexapod.model
    segment = tilt(machine)
    free = plan_validated([segment], machine, HEXAPOD_LIMITS, 1000.0, 0.0, 0.05, 2.0)
    peak_free = np.abs(forces_from_poses(hexapod, free)[3:-3]).max()
    limit = 0.5 * (56.2 + peak_free)         # 56.1 N hold the tilted platform still; the free plan needs more
    assert peak_free > limit > 56.2, peak_free
    samples = plan_validated([segment], machine, HEXAPOD_LIMITS, 1000.0, 0.0, 0.05, 2.0,
                             drive_force_limit=limit, dynamics=dynamic_model(hexapod))
    peak = np.abs(forces_from_poses(hexapod, samples)[3:-3]).max()
    assert peak <= limit * 1.005, (peak, limit)
    assert samples.duration_s > free.duration_s


def test_hexapod_platform_too_heavy_for_the_force_limit_refused_naming_the_leg(hexapod):
    with pytest.raises(TrajectoryRejected, match="leg .* cannot hold the platform .* force limit at rest"):
        plan_validated([tilt(hexapod.model)], hexapod.model, HEXAPOD_LIMITS, 1000.0, 0.0, 0.05, 2.0,
                       drive_force_limit=40.0, dynamics=dynamic_model(hexapod))


def test_archi_through_the_sub_machine_singularity_within_the_drive_limits(archi):
    """ARCHI's crossing (a leg in line with the nacelle) at the Cartesian plan's pace
    asks a drive for more than 0.06 m/s; the plan slows down there."""
    machine = archi.model
    text = "G21 G90\nG1 F30000 Y-600\nG1 X1100 Y-500 C90\nM2\n"
    segments = gcode_segments(text, machine.task_space, machine.home)
    cartesian = plan(segments, ARCHI_LIMITS)
    with pytest.raises(TrajectoryRejected, match="velocity .* exceeds 0.06"):
        validate(cartesian, machine, 0.06, 50.0)
    samples = plan_validated(segments, machine, ARCHI_LIMITS, 1000.0, 0.0, 0.06, 50.0)
    _, qdot, _ = drive_motion(machine, samples)
    assert np.abs(qdot).max() <= 0.06 * 1.001, np.abs(qdot).max()
    reference = sum(reference_duration(machine, s, ARCHI_LIMITS, 0.06, 50.0) for s in segments)
    assert abs(samples.duration_s / reference - 1.0) < 0.03, (samples.duration_s, reference)


def test_a_path_within_the_drive_limits_keeps_its_jerk_limited_cartesian_plan(hexapod):
    """Drive limits that the Cartesian plan keeps change nothing (the golden runs)."""
    machine = hexapod.model
    segment = tilt(machine)
    assert np.array_equal(plan([segment], HEXAPOD_LIMITS).position,
                          plan_validated([segment], machine, HEXAPOD_LIMITS, 1000.0, 0.0, 2.0, 50.0).position)


def test_a_path_no_speed_can_keep_is_refused_with_its_line_and_reason(archi):
    """Out of the legs' reach: refused naming the program's line and where on the path."""
    machine = archi.model
    home = np.array(machine.home, dtype=float)
    far = Line(tuple(home), tuple(home + [0.0, 3.0, 0.0]), line=7)
    with pytest.raises(TrajectoryRejected, match=r"line 7: the path leaves the machine's reach at s = 0\.\d+"):
        plan([far], ARCHI_LIMITS, drives=DriveModel(machine, DriveLimits(0.02, 0.2)))


def test_jerk_limited_where_asked_within_a_few_per_cent_of_the_acceleration_limited_optimum(hexapod):
    """The time-optimal law's velocity profile averaged over a window (its steps of
    acceleration become ramps): every task axis within its jerk and, asked for, every
    drive within 2 m/s^3 (third differences of the inverse kinematics), still within its
    velocity and acceleration limits; the price is the window."""
    machine = hexapod.model
    segment = tilt(machine)
    optimum = plan_validated([segment], machine, HEXAPOD_LIMITS, 1000.0, 0.0, 0.02, 0.2)
    samples = plan_validated([segment], machine, HEXAPOD_LIMITS, 1000.0, 0.0, 0.02, 0.2, joint_jerk_limit=2.0)
    q, qdot, qddot = drive_motion(machine, samples)
    dt = np.diff(samples.time_s)[:, None]
    jerk = np.abs(np.diff(qddot, axis=0) / dt)[3:-3].max()
    assert jerk <= 2.0 * 1.05, jerk
    assert np.abs(qdot).max() <= 0.02 * 1.001 and np.abs(qddot[2:-2]).max() <= 0.2 * 1.01
    task_jerk = np.abs(np.diff(samples.acceleration, axis=0) / dt).max(axis=0)
    assert np.all(task_jerk <= np.array(HEXAPOD_LIMITS.jerk) * 1.02), task_jerk
    ratio = samples.duration_s / optimum.duration_s
    assert 1.0 < ratio < 1.10, (samples.duration_s, optimum.duration_s)


def test_archi_force_limit_kept_under_the_controllers_infinity_norm_distribution(archi):
    """ARCHI distributes by the infinity norm (config/controller/archi.yaml): the plan keeps
    the pseudo-inverse's forces within the limit, and the controller's own need no more
    (the least largest force of all distributions), checked from the sampled poses."""
    from pkm_kinematics.distribution import min_inf_norm
    machine = archi.model
    segments = gcode_segments("G21 G90\nG1 F30000 X1100 Y-500 C90\nM2\n", machine.task_space, machine.home)
    free = plan_validated(segments, machine, ARCHI_LIMITS, 1000.0, 0.0, 2.0, 50.0)
    dynamics = dynamic_model(archi)
    peak_free = np.abs(forces_from_poses(archi, free)[3:-3]).max()
    holding = max(np.abs(np.linalg.pinv(machine.task_jacobian_batch([xi])[0].T) @ dynamics.static_forces(xi)).max()
                  for xi in free.position[::50])
    limit = 0.5 * (holding + peak_free)
    assert peak_free > limit > holding * 1.05, (peak_free, holding)
    samples = plan_validated(segments, machine, ARCHI_LIMITS, 1000.0, 0.0, 2.0, 50.0, drive_force_limit=limit,
                             dynamics=dynamics)
    t, x = samples.time_s, samples.position
    v = np.gradient(x, t, axis=0, edge_order=2)
    a = np.gradient(v, t, axis=0)
    inf_norm = np.array([np.abs(min_inf_norm(machine.task_jacobian_batch([xi])[0],
                                             dynamics.inverse_dynamics(xi, vi, ai))).max()
                         for xi, vi, ai in zip(x[3:-3], v[3:-3], a[3:-3])])
    pinv = np.abs(forces_from_poses(archi, samples)[3:-3]).max()
    assert pinv <= limit * 1.005 and inf_norm.max() <= pinv + 1e-6, (pinv, inf_norm.max(), limit)
    assert samples.duration_s > free.duration_s


def test_limits_of_another_task_space_are_refused_by_name():
    """The trajectory defaults are a planar machine's three axes: a hexapod's program
    with them was an obscure numpy broadcast error; now the limits are named."""
    machine = load_machine("genhexkins").model
    home = np.asarray(machine.home, dtype=float)
    with pytest.raises(ValueError, match=r"limits: 3 values per limit .* for genhexkins's 6 task axes \(x, y, z, a, "
                                         r"b, c\): give one per axis"):
        plan_validated([Line(tuple(home), tuple(home + [0.001, 0, 0, 0, 0, 0]), 0.01)], machine,
                       Limits((1.0,) * 3, (1.0,) * 3, (10.0,) * 3))
