"""The compiled kernels of one cycle, by the machine's task coordinates (pure core, no
rclpy), chosen once when the controller is made (no test of the task space in the
cycle):

- :class:`ThreeAxis`: planar (x, y, theta) and translational (x, y, z) machines:
  laws.limits_kernel and laws.cartesian_command_kernel (the limits, the integral,
  the law, the compiled distributions and the clamp in one call);
- :class:`SixAxis`: spatial machines (x, y, z, a, b, c): the rates of a, b, c as a
  twist, laws.spatial_limits_kernel and laws.spatial_command_kernel (the
  pseudo-inverse compiled, the other distributions from the wrench it returns).

Each answers the same five questions (``setup``: the kernels' packed inputs of a
configuration, a :class:`CommandSetup`; ``twists``: the reference's rates as the laws
take them, None when they are; ``limits``, ``joint_feedforward``, ``cartesian``); the
controller core (controller.py) acts on the answers. The joint
strategies (``joint_command``) and the distributions that are not compiled
(``distribute_wrench``) are written once for both.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pkm_common.causes import TripCause
from pkm_kinematics.distribution import distribute, raise_distribution_error, two_arm_gravity_internal_force
from pkm_kinematics.jit import direct_call
from pkm_kinematics.task_space import PLANAR, SPATIAL, task_twists

from .laws import (DIST_INF_NORM, DIST_PSEUDO_INVERSE, DISTRIBUTION_FAILED, FORCES_NOT_FINITE, LIMITS_OK,
                   MODE_DISTRIBUTION, NUMPY_DISTRIBUTION, WRENCH_NOT_FINITE, cartesian_command_kernel, joint_pid,
                   kernel_settings, limits_kernel, project_to_range, spatial_command_kernel, spatial_limits_kernel)
from .sensor_space import sensor_space_command_kernel
from .strategies import Projection
from .supervisor import Trip

__all__ = ["CartesianOutcome", "CommandSetup", "SixAxis", "ThreeAxis", "cartesian_failure", "distribute_wrench",
           "expand", "joint_command", "kernels_for"]


class CartesianOutcome(NamedTuple):
    """What a Cartesian command kernel returned: its code (laws.LIMITS_OK, a limits
    code, FORCES_NOT_FINITE, WRENCH_NOT_FINITE, or DISTRIBUTION_FAILED + the
    distribution's), the index and value it names (the translation error when OK),
    the new integral state, the wrench (the kernel's array: ``wrench_list`` of the
    kernels reads it as the messages show it), the drive forces (list, every drive;
    meaningful when ``distributed``), the saturation count and the peak force."""
    code: int
    index: int
    value: float
    integral: object
    wrench: np.ndarray
    forces: list
    distributed: bool          # the kernel distributed and clamped the forces itself
    saturated: int
    peak: float


class CommandSetup(NamedTuple):
    """The packed inputs of the limits and command kernels that one configuration
    fixes (laws.py: ``boxes``, ``settings``, ``modes``), made when the controller is
    configured and when its settings change, not in the cycle."""
    boxes: tuple               # (joint_box, workspace_box)
    gains: np.ndarray          # the law's rows kp, kd, ki, mass per task axis (tuning.ScaledGains.law_gains)
    settings: tuple            # laws.kernel_settings
    modes: tuple               # (planar, law, distribution) with every drive active
    degraded_modes: tuple      # the same with a drive dropped


# a CartesianOutcome is made with tuple.__new__ (NamedTuple's own __new__ is a Python call, once a cycle)
_NEW = tuple.__new__


class ThreeAxis:
    """Planar and translational machines (3 task coordinates)."""

    def __init__(self, model):
        self.model = model
        self.planar = model.task_space is PLANAR

    twists = None        # the reference's rates are what the laws take: nothing to convert

    def setup(self, config, tuned, boxes: tuple, n: int) -> CommandSetup:
        """The compiled distributions where they apply (no prestress; the pseudo-inverse,
        or ARCHI's inf-norm on 4 drives), else numpy's from the returned wrench; a
        drive dropped: the compiled pseudo-inverse."""
        distribution = NUMPY_DISTRIBUTION
        if config.prestress_n == 0.0 and (config.distribution == "pseudo_inverse" or (
                config.distribution == "inf_norm" and n == 4)):
            distribution = DIST_PSEUDO_INVERSE if config.distribution == "pseudo_inverse" else DIST_INF_NORM
        planar = int(self.planar)
        return CommandSetup(boxes, tuned.law_gains,
                            kernel_settings(config.max_condition, config.following_error_m,
                                            config.following_error_rad, config.force_limit_n),
                            (planar, tuned.law, distribution), (planar, tuned.law, DIST_PSEUDO_INVERSE))

    @staticmethod
    def wrench_list(wrench) -> list:
        return list(wrench)

    def limits(self, q, active_rows, measured, error, setup: CommandSetup) -> tuple[int, int, float]:
        return limits_kernel(q, active_rows, tuple(measured), tuple(error), setup.boxes, setup.settings, self.planar)

    def joint_feedforward(self, joint_mass, rows_d, a_d, bias_d) -> list:
        """m_i (J a_d + Jdot v_d)_i per drive (ARCHI §3.4)."""
        return [m * (j0 * a_d[0] + j1 * a_d[1] + j2 * a_d[2] + b)
                for m, (j0, j1, j2), b in zip(joint_mass, rows_d, bias_d)]

    def cartesian(self, core, c, measured, error) -> CartesianOutcome:
        """laws.cartesian_command_kernel on the prepared cycle ``c``; with a drive dropped
        the compiled pseudo-inverse distributes."""
        active = core.supervisor.active
        full = len(active) == core.n
        code, index, value, integral, wrench, forces, saturated, peak = _cartesian_call(
            c.q_array, c.active_rows, (tuple(measured), tuple(error), tuple(c.v_d), c.v, tuple(c.a_d)),
            *_law_inputs(core, c, full))
        return self.outcome(core, active, full, code, index, value, integral, wrench, forces, saturated, peak)

    def sensor_space(self, core, c, struts) -> tuple[tuple, tuple, CartesianOutcome]:
        """The sensor-space feedback on the strut readings ``struts`` (checked) and
        :meth:`cartesian` in one compiled call (sensor_space.sensor_space_command_kernel):
        (measured, error, the outcome); the feedback's estimate of the real plate kept."""
        active, feedback = core.supervisor.active, core.metrology
        full = len(active) == core.n
        x = c.x_d
        j_h, l_des, p_bp, r_bp, r_wb, p_tp, t = feedback.prepared()
        real_p, real_r, measured, error, code, index, value, integral, wrench, forces, saturated, peak = \
            _sensor_space_call(
                j_h, l_des, np.asarray(struts, dtype=float), p_bp, r_bp, r_wb, p_tp, t,
                (float(x[0]), float(x[1]), float(x[2])), c.q_array, c.active_rows, tuple(c.v_d), c.v, tuple(c.a_d),
                *_law_inputs(core, c, full))
        feedback.estimate = (real_p, real_r)
        return measured, error, self.outcome(core, active, full, code, index, value, integral, wrench, forces,
                                              saturated, peak)

    @staticmethod
    def outcome(core, active, full, code, index, value, integral, wrench, forces, saturated, peak):
        distributed = bool(forces.shape[0])
        if distributed:
            forces = forces.tolist() if full else expand(forces.tolist(), active, core.n)
        return _NEW(CartesianOutcome, (code, index, value, integral, wrench, forces if distributed else [],
                                       distributed, saturated, peak))


def _law_inputs(core, c, full: bool) -> tuple:
    """The 3-axis command kernels' inputs after the task's: (A, H), the integral,
    whether it integrates (the last command not saturated), dt and the configuration's
    boxes, gains, settings and modes (all drives, or one dropped)."""
    s = core.setup
    return ((c.a_model, c.h_model), core.integral, core.record.saturated == 0, c.dt, s.boxes, s.gains, s.settings,
            s.modes if full else s.degraded_modes)


class SixAxis:
    """Spatial machines (x, y, z, a, b, c)."""

    def __init__(self, model):
        self.model = model
        self.space = model.task_space

    def setup(self, config, tuned, boxes: tuple, n: int) -> CommandSetup:
        """The pseudo-inverse compiled with every drive and no prestress; the other
        distributions, and a machine with a drive dropped, from the returned wrench."""
        compiled = config.distribution == "pseudo_inverse" and config.prestress_n == 0.0
        return CommandSetup(boxes, tuned.law_gains,
                            kernel_settings(config.max_condition, config.following_error_m,
                                            config.following_error_rad, config.force_limit_n,
                                            self.model.characteristic_length_m),
                            (0, tuned.law, DIST_PSEUDO_INVERSE if compiled else NUMPY_DISTRIBUTION),
                            (0, tuned.law, NUMPY_DISTRIBUTION))

    def twists(self, x_d, v_d, a_d):
        """The rates of a, b, c -> the twist and its rate (w in the base frame)."""
        return task_twists(self.space, x_d, v_d, a_d)

    @staticmethod
    def wrench_list(wrench) -> list:
        return wrench.tolist()

    def limits(self, q, active_rows, measured, error, setup: CommandSetup) -> tuple[int, int, float]:
        return spatial_limits_kernel(q, active_rows, np.asarray(measured, dtype=float), np.asarray(error, dtype=float),
                                     setup.boxes, setup.settings)

    def joint_feedforward(self, joint_mass, rows_d, a_d, bias_d) -> list:
        return (np.asarray(joint_mass) * (rows_d @ np.asarray(a_d) + bias_d)).tolist()

    def cartesian(self, core, c, measured, error) -> CartesianOutcome:
        """laws.spatial_command_kernel on the prepared cycle ``c``: the pseudo-inverse
        compiled with every drive and no prestress, else the wrench only."""
        s = core.setup
        modes = s.modes if len(core.supervisor.active) == core.n else s.degraded_modes
        code, index, value, integral, wrench, forces, saturated, peak = spatial_command_kernel(
            c.q_array, c.active_rows, np.array((measured, error, c.v_d, c.v, c.a_d), dtype=float),
            (c.a_model, c.h_model), np.asarray(core.integral, dtype=float), core.record.saturated == 0, c.dt,
            s.boxes, s.gains, s.settings, modes)
        return _NEW(CartesianOutcome, (code, index, value, tuple(integral.tolist()), wrench, forces.tolist(),
                                       modes[MODE_DISTRIBUTION] == DIST_PSEUDO_INVERSE and code == LIMITS_OK,
                                       saturated, peak))


def kernels_for(model) -> ThreeAxis | SixAxis:
    """The kernels of ``model``'s task coordinates."""
    return SixAxis(model) if model.task_space is SPATIAL else ThreeAxis(model)


def joint_command(model, kernels, tuned, config, projection: Projection, active: list, n: int, integral, c):
    """joint_pid (ARCHI §4.1), decentralized_projected (Sliding Star eq. 6-8) and
    decentralized_integral_projected (its Fig. 9) on the prepared cycle ``c``:
    (the drive forces, before the clamp; the new integral state)."""
    q, qdot, x_d, v_d, a_d, dt = c.q, c.qdot, c.x_d, c.v_d, c.a_d, c.dt
    q_d, rows_d, qdot_d, bias_d = model.velocity_terms(x_d, v_d)
    # acceleration feed-forward with the mass each drive sees, as industrial
    # drives have: qddot_d = J a_d + Jdot v_d (ARCHI §3.4)
    feedforward = kernels.joint_feedforward(tuned.joint_mass, rows_d, a_d, bias_d)
    e = [a - b for a, b in zip(q_d, q)]
    edot = [a - b for a, b in zip(qdot_d, qdot)]
    limit = config.force_limit_n
    integral = [min(limit, max(-limit, i + ki * ei * dt))
                for i, ki, ei in zip(integral, tuned.joint_ki, e)]
    active_rows = c.active_rows
    if projection != Projection.NONE:
        # the integral state in range(J): no wind-up along ker(J^T) (Sliding Star
        # Fig. 9 projects only this component; eq. 8 the whole command below)
        sub = project_to_range(active_rows, [integral[k] for k in active])
        integral = [0.0] * n
        for k, f in zip(active, sub):
            integral[k] = f
    n_d = [f + ff for f, ff in zip(joint_pid(e, edot, integral, tuned.joint_kp, tuned.joint_kd), feedforward)]
    if projection != Projection.FORCES:
        return [n_d[k] if k in active else 0.0 for k in range(n)], integral
    sub = project_to_range(active_rows, [n_d[k] for k in active])     # eq. 8
    return expand(sub, active, n), integral


def expand(sub, active: list, n: int) -> list:
    """Forces of the ``active`` drives -> forces of all ``n`` (0 for a dropped one)."""
    if len(active) == n:
        return list(sub)
    out = [0.0] * n
    for k, f in zip(active, sub):
        out[k] = f
    return out


def distribute_wrench(config, dynamics, model, wrench, active_rows, pose, active: list, n: int) -> list:
    """The distributions that are not compiled (p_norm, two_arm, a prestress); with a
    drive dropped, the pseudo-inverse over the ``active`` ones (0 for the others)."""
    if len(active) < n:
        return expand(distribute("pseudo_inverse", active_rows, wrench).tolist(), active, n)
    internal = 0.0
    if config.distribution == "two_arm_gravity":
        p = dynamics.params
        internal = two_arm_gravity_internal_force(p.platform_mass_kg, float(pose[2]), p.gravity_m_s2)
    return distribute(config.distribution, active_rows, wrench, machine=model, pose=pose, p=config.p_norm,
                      internal_force_n=internal, prestress_n=config.prestress_n,
                      reference=[1.0] * len(active_rows),
                      prestress_direction=config.prestress_direction or None).tolist()


def cartesian_failure(code: int, index: int, value: float, wrench: list, forces, strategy: str, supervisor) -> Trip:
    """The trip of a Cartesian kernel's outcome other than LIMITS_OK: a limit's (the
    supervisor names it), a non-finite wrench or forces; a compiled distribution that
    failed raises the DistributionError numpy's would (its caller trips on it)."""
    if code > DISTRIBUTION_FAILED:
        raise_distribution_error(code - DISTRIBUTION_FAILED, index, value, wrench)
    if code == FORCES_NOT_FINITE:
        return Trip(f"{strategy}: non-finite drive forces {forces}", TripCause.KINEMATICS)
    if code == WRENCH_NOT_FINITE:
        return Trip(f"{strategy}: wrench: contains NaN or infinite values: {wrench}", TripCause.KINEMATICS)
    return supervisor.limit_trip(code, index, value)


# the per-cycle calls without the dispatcher's typing (jit.direct_call): every argument is
# made above with its declared type (PKM_CHECK_DIRECT_CALLS=1 checks it: tests/kinematics/test_jit.py)
_cartesian_call = direct_call(cartesian_command_kernel)
_sensor_space_call = direct_call(sensor_space_command_kernel)
