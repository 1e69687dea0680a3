"""The integral time a PID law may have on a machine: every mode of the hold must be
stable, not only the one whose mass the gains were scaled by. hexapod8's joint PIDs
see 6 % of the task mass in two modes (x-roll, y-pitch); with the default T_i = 0.05 s
a hold grew from the encoders' quantisation into a following-error trip ~10 s in.
The bound (laws.weakest_mode_ratio, Routh per mode) is checked here against the
eigenvalues of the linear closed loop, and enforced at configure."""

import math

import numpy as np
import pytest
import scipy.linalg

from pkm_controller.controller import ControllerConfig, ControllerCore
from pkm_controller.laws import Gains, weakest_mode_ratio
from pkm_kinematics import load_machine


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
    a, jac, m_joint = core.home_masses()
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
