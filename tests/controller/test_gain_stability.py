"""The integral time a PID law may have on a machine: every mode of the hold must be
stable, not only the one whose mass the gains were scaled by. hexapod8's joint PIDs
see 6 % of the task mass in two modes (x-roll, y-pitch); with the default T_i = 0.05 s
a hold grew from the encoders' quantisation into a following-error trip ~10 s in.
The bound (laws.weakest_mode_ratio, Routh per mode) is checked here against the
eigenvalues of the linear closed loop, and enforced at configure.

Sampled, the loop has a second bound, on its stiff modes: hexapod8's joint PIDs at
250 Hz saturated at 2,000 N from the start at 20 Hz (mass ratio 2.77), and MoM3's
(2.16) tripped on a false encoder slip 50 ms after a kick. laws.sampled_hold_radius
is checked against the exact step of the mode (a matrix exponential) and against the
simulated plant: what it refuses grows there, what it accepts holds 60 s."""

import math

import numpy as np
import pytest
import scipy.linalg

from pkm_controller.config import ControllerConfig

from pkm_controller.controller import ControllerCore
from pkm_controller.laws import Gains, sampled_hold_radius, sampled_mode_matrix, weakest_mode_ratio
from pkm_kinematics import load_machine
from pkm_sim_hw.parameters import PLANTS
from pkm_sim_hw.plant import Plant, PlantParameters


def closed_loop_growth(shape, a, gains: Gains) -> float:
    """The largest real part of the eigenvalues of A x'' = -K (kd x' + kp x + ki int x),
    K = ``shape`` (the linearised hold; state: int x, x, x')."""
    d = len(a)
    a_inv_k = np.linalg.solve(a, shape)
    z, i = np.zeros((d, d)), np.eye(d)
    m = np.block([[z, i, z], [z, z, i], [-gains.ki * a_inv_k, -gains.kp * a_inv_k, -gains.kd * a_inv_k]])
    return float(np.linalg.eigvals(m).real.max())


def test_the_weakest_mode_ratio_is_the_smallest_generalised_eigenvalue():
    rng = np.random.default_rng(3)
    for d in (3, 6):
        for _ in range(20):
            x = rng.normal(size=(d, d))
            a = x @ x.T + d * np.eye(d)
            y = rng.normal(size=(d + 2, d))
            k = y.T @ np.diag(rng.uniform(0.1, 3.0, d + 2)) @ y
            assert math.isclose(weakest_mode_ratio(k, a), scipy.linalg.eigh(k, a, eigvals_only=True)[0],
                                rel_tol=1e-9)
        assert math.isclose(weakest_mode_ratio(2.5 * a, a), 2.5, rel_tol=1e-12)


@pytest.mark.parametrize("name", ["archi", "hexapod8", "genhexkins"])
def test_the_integral_time_bound_is_where_the_closed_loop_turns_unstable(name):
    machine = load_machine(name)
    core = ControllerCore(machine, ControllerConfig(strategy="computed_torque"))
    a, jac, m_joint = core.tuning.home_masses()
    shape = jac.T @ np.diag(m_joint) @ jac
    r = weakest_mode_ratio(shape, a)
    omega, zeta = 2 * math.pi * 20.0, 1.0
    bound = 1.0 / (2 * zeta * omega * r)
    assert closed_loop_growth(shape, a, Gains(omega, zeta, 0.95 * bound)) > 0.0
    assert closed_loop_growth(shape, a, Gains(omega, zeta, 1.05 * bound)) < 0.0


def test_a_joint_pid_whose_integral_cannot_hold_a_mode_is_refused_at_configure():
    hexapod = load_machine("hexapod8")
    with pytest.raises(ValueError, match=r"integral_time_s: must be 0, or in \(0\.06\d+, inf\) s for "
                                         r"joint_pid on hexapod8 .*mass ratio 0\.059"):
        ControllerCore(hexapod, ControllerConfig(strategy="joint_pid", integral_time_s=0.05))
    for strategy, t_i in (("joint_pid", 0.1), ("decentralized_projected", 0.0), ("cartesian_pid", 0.05)):
        ControllerCore(hexapod, ControllerConfig(strategy=strategy, integral_time_s=t_i))
    # a change while running is held to the same bound, nothing changed
    core = ControllerCore(hexapod, ControllerConfig(strategy="cartesian_pid"))
    with pytest.raises(ValueError, match="integral_time_s: must be 0, or in"):
        core.change_settings({"strategy": "decentralized_projected"})
    assert core.config.strategy == "cartesian_pid"


def exact_mode_step(r: float, gains: Gains, dt: float) -> np.ndarray:
    """The mode's step from (z, zdot, I) with the command held over dt, by the matrix
    exponential of the continuous motion (z, zdot, zddot held): a second reader of
    sampled_mode_matrix's exact form."""
    kp, kd, ki = gains.kp, gains.kd, gains.ki
    motion = scipy.linalg.expm(np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]) * dt)
    out = np.zeros((3, 3))
    for j in range(3):
        state = np.eye(3)[j]
        integral = state[2] - ki * dt * state[0]                      # I_{k+1}, then the command
        acc = r * (-kp * state[0] - kd * state[1] + integral)
        z, zdot, _ = motion @ np.array([state[0], state[1], acc])
        out[:, j] = (z, zdot, integral)
    return out


@pytest.mark.parametrize("r, bandwidth_hz, zeta, t_i, dt", [
    (2.768, 20.0, 1.0, 0.1, 0.004), (0.059, 20.0, 1.0, 0.1, 0.001), (1.0, 25.0, 0.1, 0.05, 0.004)])
def test_the_sampled_mode_is_the_exact_step_of_the_held_command(r, bandwidth_hz, zeta, t_i, dt):
    gains = Gains(2 * math.pi * bandwidth_hz, zeta, t_i)
    np.testing.assert_allclose(sampled_mode_matrix(r, gains, dt), exact_mode_step(r, gains, dt), rtol=1e-12,
                               atol=1e-12)
    # small dt: the continuous bound (Routh) is its limit
    bound = 1.0 / (2 * zeta * gains.omega * 0.5)
    for factor, stable in ((0.95, False), (1.05, True)):
        slow = Gains(gains.omega, zeta, factor * bound)
        assert (sampled_hold_radius(0.5, slow, 1e-5) < 1.0) == stable, factor


def hold_with_a_kick(name: str, strategy: str, configured_dt: float, dt: float, bandwidth_hz: float,
                     t_i: float, seconds: float) -> tuple:
    """Hold still at home under the sim's plant stepped every ``dt``, with 5 N kicks on
    the first 5 steps; the core is configured for ``configured_dt`` (its gains do not
    depend on it: the integral uses the states' stamps), so that a setting refused at
    ``dt`` can still be run. Returns (largest move of the tool after 0.5 s (m), the
    stop reason or "")."""
    machine = load_machine(name)
    core = ControllerCore(machine, ControllerConfig(strategy=strategy, dt_s=configured_dt, bandwidth_hz=bandwidth_hz,
                                                    integral_time_s=t_i, distribution="pseudo_inverse"))
    plant = PLANTS.get(machine.kind, Plant)(machine, PlantParameters(dt_s=dt))
    out = plant.output()
    home, worst = np.array(out.tool_pose[:3]), 0.0
    for k in range(round(seconds / dt)):
        forces = core.update(out.stamp_ns, out.encoder_positions, out.encoder_velocities, out.applied_forces)
        if core.stopped:
            return math.inf, core.stop_reason
        if k < 5:
            forces = [f + 5.0 * (-1) ** (i + k) for i, f in enumerate(forces)]
        out = plant.step(forces)
        if k * dt > 0.5:
            worst = max(worst, float(np.abs(np.array(out.tool_pose[:3]) - home).max()))
    return worst, ""


@pytest.mark.parametrize("name, bandwidth_hz, t_i, stable_words", [
    ("hexapod8", 15.0, 0.15, r"stable for bandwidth_hz in \[\d.*, 1[23]\.\d+\] Hz"),
    ("mom3", 20.0, 0.05, r"stable for bandwidth_hz in \[\d.*, 1\d\.\d+\] Hz"),
])
def test_gains_unstable_when_sampled_are_refused_and_grow_on_the_plant(name, bandwidth_hz, t_i, stable_words):
    machine = load_machine(name)
    with pytest.raises(ValueError, match=rf"bandwidth_hz: joint_pid on {name} sampled at 250 Hz is unstable at "
                                         rf"{bandwidth_hz:g} Hz .*{stable_words}") as refused:
        ControllerCore(machine, ControllerConfig(strategy="joint_pid", dt_s=0.004, bandwidth_hz=bandwidth_hz,
                                                 integral_time_s=t_i))
    # what the check refused, run anyway: the kick grows into a trip or millimetres within 2 s
    worst, stop = hold_with_a_kick(name, "joint_pid", 0.001, 0.004, bandwidth_hz, t_i, 2.0)
    assert stop or worst > 100e-6, (worst, str(refused.value))
    # and the change of settings while running is held to the same check
    core = ControllerCore(machine, ControllerConfig(strategy="joint_pid", dt_s=0.004, bandwidth_hz=10.0,
                                                    integral_time_s=0.2))
    with pytest.raises(ValueError, match="sampled at 250 Hz is unstable"):
        core.change_settings({"bandwidth_hz": bandwidth_hz, "integral_time_s": t_i})
    assert core.config.bandwidth_hz == 10.0


@pytest.mark.parametrize("dt, bandwidth_hz, t_i", [(0.004, 12.0, 0.2), (0.001, 20.0, 0.1)])
def test_hexapod8s_joint_pids_hold_a_minute_with_gains_the_check_accepts(dt, bandwidth_hz, t_i):
    """The issue's bar: 60 s within 10 um after a kick, at 250 Hz and 1 kHz (its
    default T_i 0.05 s is refused by name, test above; these are the ones that hold)."""
    worst, stop = hold_with_a_kick("hexapod8", "joint_pid", dt, dt, bandwidth_hz, t_i, 60.0)
    assert not stop and worst < 10e-6, (worst * 1e6, stop)
