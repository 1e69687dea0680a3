"""What gains a machine can take (pure core, no rclpy): the checks of a configuration
that only the machine can answer, and the gains scaled to its masses.

The gains are given as a bandwidth, a damping ratio and an integral time
(laws.Gains); they act in N/m through the nominal mass at home: the task mass
diag(A(x_home)) for the Cartesian laws, the mass each drive sees for the joint PIDs
(diag(J^+T A J^+) on the 3-DOF machines, the apparent mass 1 / (J A^-1 J^T)_ii on a
spatial one: laws.apparent_drive_mass). A PID law whose gains' shape differs from
the task mass has modes of other mass ratios (laws.mode_ratios): each must keep its
stiffness, a stable integral (T_i > 1 / (2 zeta omega r)) and a stable sampled hold
(laws.sampled_hold_radius). The integral state a PID law starts from holds the
machine where it is (``holding_integral``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pkm_kinematics.distribution import TWO_ARM, prestress_direction
from pkm_kinematics.dynamics import holding_forces
from pkm_kinematics.errors import DistributionError, FieldError, KinematicsError
from pkm_kinematics.planar import pair_force_map
from pkm_kinematics.task_space import PLANAR, SPATIAL

from .commands import expand
from .config import ControllerConfig
from .laws import (LAW_CARTESIAN_PID, LAW_COMPUTED_TORQUE, LAW_VELOCITY_CASCADE, Gains, apparent_drive_mass,
                   mode_ratios, sampled_hold_radius)
from .strategies import Law, strategy

__all__ = ["MachineTuning", "ScaledGains", "holding_integral", "zero_integral"]


@dataclass(frozen=True)
class ScaledGains:
    """A configuration's gains on one machine: per task axis and per drive (N/m, N s/m,
    N/(m s)), and the law code and gain rows (kp, kd, ki, mass per task axis) of
    laws.cartesian_command_kernel."""
    gains: Gains
    task_mass: list
    task_kp: list
    task_kd: list
    task_ki: list
    joint_mass: list
    joint_kp: list
    joint_kd: list
    joint_ki: list
    law: int
    law_gains: np.ndarray


class MachineTuning:
    """One machine's side of the gains (its masses and modes at home, computed once)."""

    def __init__(self, machine, dynamics):
        self.machine, self.model, self.dynamics = machine, machine.model, dynamics
        self.space = self.model.task_space
        self.dof, self.n = self.space.dof, self.model.n_legs
        self.planar, self.spatial = self.space is PLANAR, self.space is SPATIAL
        self.home = self.home_masses()
        a, jac, m_joint = self.home
        # the mass ratios of the modes of each PID law at home, ascending, distinct. Every
        # other law acts through A(x): its modes are all 1
        self.mode_ratios = {law: tuple(sorted({round(float(r), 9) for r in mode_ratios(shape, a)}))
                            for law, shape in ((Law.JOINT_PID, jac.T @ np.diag(m_joint) @ jac),
                                               (Law.CARTESIAN_PID, np.diag(np.diag(a))))}

    def home_masses(self) -> tuple[np.ndarray, np.ndarray, list]:
        """(A(x_home), J_m(x_home), the mass each drive sees there): the scale of the gains."""
        home = self.model.home.tolist()
        if self.spatial:
            a, _, rows, _ = self.dynamics.measured_state(home, [0.0] * self.n)
            return np.asarray(a), np.asarray(rows), apparent_drive_mass(rows, a).tolist()
        a, _, rows, _, _ = self.dynamics.terms(home, (0.0, 0.0, 0.0))
        jac, a = np.array(rows), np.array(a)
        pinv = np.linalg.pinv(jac)                           # 3 x n
        return a, jac, np.diag(pinv.T @ a @ pinv).tolist()

    def check(self, config: ControllerConfig) -> None:
        """ControllerConfig.validate, and what only this machine can say (ValueError
        naming the parameter and its range)."""
        name = self.machine.name
        config.validate(self.n, self.planar)
        ratios = self.mode_ratios.get(strategy(config.strategy).law, (1.0,))
        ratio = ratios[0]
        if ratio <= 0.0:
            raise FieldError("strategy", f"{config.strategy} on {name}: its gains leave a mode of the "
                                         f"machine at home without stiffness (mass ratio {ratio:.3g})")
        if config.integral_time_s != 0.0 and ratio < 1.0:
            low = 1.0 / (2.0 * config.damping_ratio * 2.0 * math.pi * config.bandwidth_hz * ratio)
            if config.integral_time_s <= low:
                raise FieldError("integral_time_s", f"must be 0, or in ({low:.4g}, inf) s for {config.strategy} on "
                                                    f"{name} (stability of its weakest mode, mass ratio {ratio:.3g}: "
                                                    f"T_i > 1 / (2 zeta omega r)), got {config.integral_time_s!r}")
        self._check_sampled(config, ratios)
        if config.prestress_n != 0.0 and self.n <= self.dof:
            raise FieldError("prestress_n", f"must be 0 on a machine without redundant drives ({self.n} drives for "
                                            f"{self.dof} DOF: no internal force exists)")
        if config.prestress_direction:
            try:                       # at home: a pattern with no internal part would trip the first cycle
                prestress_direction(self.model.jacobian(self.model.home), config.prestress_direction)
            except DistributionError as exc:
                raise FieldError("prestress_direction", f"{exc} at home") from None
        if self.spatial and config.forward_kinematics != "newton":
            raise FieldError("forward_kinematics", f"must be newton on a {self.dof}-DOF machine "
                                                   f"(the integrated forms are written for 3 task coordinates), got "
                                                   f"{config.forward_kinematics!r}")
        if config.distribution in TWO_ARM:
            try:                       # a planar machine of 4 drives whose legs do not pair up (Sliding Star)
                pair_force_map(self.model, self.model.home)
            except ValueError as exc:
                raise FieldError("distribution", f"{config.distribution} needs two pairs of legs sharing a "
                                                 f"platform point (ARCHI §4.3): {exc}") from None

    def _check_sampled(self, config: ControllerConfig, ratios) -> None:
        """Refuse gains whose hold is unstable as sampled every ``config.dt_s``
        (laws.sampled_hold_radius, every mode of the law), naming the bandwidths that
        are stable with the same damping and integral time (ValueError)."""
        def radii(bandwidth_hz: float) -> list:
            gains = Gains(2.0 * math.pi * bandwidth_hz, config.damping_ratio, config.integral_time_s)
            return [sampled_hold_radius(r, gains, config.dt_s) for r in ratios]
        now = radii(config.bandwidth_hz)
        worst = int(np.argmax(now))
        if now[worst] < 1.0:
            return
        top = 0.1 / config.dt_s                              # ControllerConfig's own bound
        stable = [b for b in np.geomspace(0.1, top, 160) if max(radii(b)) < 1.0]
        where = (f"stable for bandwidth_hz in [{min(stable):.3g}, {max(stable):.3g}] Hz" if stable else
                 "no bandwidth is stable with this damping and integral time (a longer integral_time_s or "
                 "a higher damping_ratio widens the range)")
        raise FieldError("bandwidth_hz",
                         f"{config.strategy} on {self.machine.name} sampled at {1.0 / config.dt_s:g} Hz is unstable "
                         f"at {config.bandwidth_hz:g} Hz (damping_ratio {config.damping_ratio:g}, integral_time_s "
                         f"{config.integral_time_s:g}): its mode of mass ratio {ratios[worst]:.3g} grows "
                         f"{now[worst]:.4f}x per cycle; {where} (or a faster control rate), got "
                         f"{config.bandwidth_hz!r}")

    def scaled(self, config: ControllerConfig) -> ScaledGains:
        """The gains of ``config`` on this machine. The law's gain rows: the scaled task
        gains for cartesian_pid; per unit mass for computed_torque (A(x) scales them);
        the cascade's outer PI and inner velocity gain Kv for the metrology strategies."""
        g = Gains(2.0 * math.pi * config.bandwidth_hz, config.damping_ratio, config.integral_time_s)
        a, _, m_joint = self.home
        a = a.tolist()
        m_task = [a[i][i] for i in range(self.dof)]
        task_kp, task_kd, task_ki = [g.kp * m for m in m_task], [g.kd * m for m in m_task], [g.ki * m for m in m_task]
        law, d = strategy(config.strategy).law, self.dof
        if law == Law.CARTESIAN_PID:
            code, rows = LAW_CARTESIAN_PID, np.array([task_kp, task_kd, task_ki, m_task])
        elif law == Law.COMPUTED_TORQUE:
            code, rows = LAW_COMPUTED_TORQUE, np.array([[g.kp] * d, [g.kd] * d, [g.ki] * d, [0.0] * d])
        else:
            code, rows = LAW_VELOCITY_CASCADE, np.array([[g.outer_kp] * d, [g.kd] * d, [g.outer_ki] * d, [0.0] * d])
        return ScaledGains(g, m_task, task_kp, task_kd, task_ki, m_joint, [g.kp * m for m in m_joint],
                           [g.kd * m for m in m_joint], [g.ki * m for m in m_joint], code, rows)


    def takeover(self, running: ControllerConfig, changes: dict, pose, active: list):
        """(the configuration, the integral state) of a running controller's settings
        change (ControllerCore.change_settings): ``changes`` applied to ``running`` and
        validated like a start-up configuration; a strategy only to one fed by the same
        measurement (the graph's topics stay). The integral is None when the law stays
        (the state is kept: a joint PID with or without the projection), else the one
        that holds the load at the measured ``pose`` (holding_integral; zero for a
        model-based law). ValueError naming the field and its range."""
        new = running.with_changes(changes)
        self.check(new)
        old_strategy, new_strategy = strategy(running.strategy), strategy(new.strategy)
        if new_strategy.feedback != old_strategy.feedback:
            raise FieldError("strategy", f"{new.strategy} feeds back {new_strategy.feedback.value}, the running "
                                         f"{old_strategy.name} {old_strategy.feedback.value}: only a strategy on the "
                                         f"same measurement can take over without a restart")
        if new_strategy.law == old_strategy.law:
            return new, None
        try:
            return new, holding_integral(self.dynamics, self.model, pose, new_strategy.law, new.integral_time_s,
                                         active)
        except (KinematicsError, ValueError, np.linalg.LinAlgError) as exc:
            raise FieldError("strategy", f"{new.strategy} cannot take over holding at the measured pose: "
                                         f"{exc}") from None


def zero_integral(law: Law, n: int, dof: int):
    """The integral state at zero of ``law``: per drive for the joint PIDs, per task
    axis otherwise."""
    return [0.0] * n if law == Law.JOINT_PID else (0.0,) * dof


def holding_integral(dynamics, model, pose, law: Law, integral_time_s: float, active: list, rows=None):
    """The integral state that holds the machine still at ``pose``: the nominal
    model's static forces H(x, 0) (ARCHI §3.4), as drive forces of minimum 2-norm
    (in range(J), where the projected PIDs keep their integral) for a joint PID, as
    the task wrench for the Cartesian PID, as a drive holds its load before the
    brake opens. These laws have no gravity term but their integral: started at
    zero, the platform fell until the integral caught up (ARCHI at 20 Hz: 0.9 mm,
    4 mm at the panel's 8 Hz, a following-error trip with a few late commands).
    Zero for the model-based laws, whose H(x, v) holds it already, without an
    integral (``integral_time_s`` 0: a P(D) law, as the paper's), and before the
    first pose. ``rows``: J_m of the ``active`` drives at ``pose`` if known. Raises
    KinematicsError (DistributionError) at a singular pose."""
    n = model.n_legs
    if pose is None or integral_time_s == 0.0 or law not in (Law.JOINT_PID, Law.CARTESIAN_PID):
        return zero_integral(law, n, model.task_space.dof)
    if law == Law.CARTESIAN_PID:
        return tuple(float(w) for w in dynamics.static_forces(pose))
    if rows is None:
        rows = np.asarray(model.jacobian(pose), dtype=float)[active]
    return [float(f) for f in expand(holding_forces(dynamics, rows, pose), active, n)]
