"""Self-calibration of ARCHI from its own redundancy (four drives, three degrees of
freedom; MoM3 §3's dosr = 1), no instrument: the closures' Jacobians against central
differences, the blind spots named (the platform frame's and the base frame's gauge:
5 of 20), archi_fig12's 2 % leg error and injected errors on every identifiable
parameter recovered from noise-free readings (readings from the closed-form inverse
kinematics of the true machine, independent of the model's residuals)."""

import numpy as np
import pytest
from finite_differences import central_differences, worst_column      # tests/finite_differences.py

from pkm_calibration.self_calibration import PlanarRailErrorModel, self_calibrate
from pkm_kinematics import bars as B
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError


@pytest.fixture(scope="module")
def model():
    return PlanarRailErrorModel(load_machine("archi").model)


def poses_about_home(machine, n, seed):
    rng = np.random.default_rng(seed)
    return machine.home + rng.uniform([-0.3, -0.15, -1.0], [0.3, 0.15, 1.0], size=(n, 3))


def true_readings(machine, theta, poses):
    """The encoders of the machine with errors ``theta`` at ``poses``: each carriage's
    closed form s = u.w + sigma sqrt(L^2 - |w|^2 + (u.w)^2), w = B - a (ARCHI §3.1),
    read s - z."""
    bars = machine.bars
    t = np.asarray(theta).reshape(machine.n_legs, 5)
    out = np.zeros((len(poses), machine.n_legs))
    for i, (x, y, th) in enumerate(poses):
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        for k in range(machine.n_legs):
            u = bars[k, B.COL_U:B.COL_U + 2]
            a = bars[k, B.COL_A:B.COL_A + 2] + t[k, 4] * np.array([-u[1], u[0]])
            w = np.array([x, y]) + rot @ (bars[k, B.COL_B:B.COL_B + 2] + t[k, 2:4]) - a
            length = bars[k, B.COL_LENGTH] + t[k, 0]
            s = u @ w + bars[k, B.COL_BRANCH] * np.sqrt(length ** 2 - w @ w + (u @ w) ** 2)
            out[i, k] = s - t[k, 1]
    return out


def test_the_closures_jacobians_are_their_derivatives(model):
    machine = model.machine
    xs = poses_about_home(machine, 10, 1)
    theta = np.random.default_rng(2).normal(0, 1e-3, model.size)
    q = true_readings(machine, theta, xs)
    d_pose, d_theta = model.jacobian(theta, xs, q)
    error, j = worst_column(central_differences(lambda t: model.residuals(t, xs, q), theta), d_theta)
    assert error < 1e-7, model.names[j]
    error, j = worst_column(central_differences(lambda x: model.residuals(theta, x, q), xs), d_pose)
    assert error < 1e-7, j


def test_the_redundancy_identifies_15_of_20_and_names_the_rest(model):
    xs = poses_about_home(model.machine, 40, 3)
    which = model.identifiability(xs, true_readings(model.machine, np.zeros(model.size), xs))
    assert len(which.identified) == 15 and len(which.held) == 5, which.describe()


def test_fig12s_leg_error_and_every_identifiable_one_recovered_without_an_instrument(model):
    machine = model.machine
    xs = poses_about_home(machine, 40, 4)
    held = model.identifiability(xs, true_readings(machine, np.zeros(model.size), xs)).held
    truth = np.random.default_rng(5).normal(0, 5e-4, model.size)
    truth[model.names.index("length.q3")] = 0.02 * machine.bars[2, B.COL_LENGTH]    # archi_fig12: leg 3 2 % long
    truth[list(held)] = 0.0
    q = true_readings(machine, truth, xs)
    result = self_calibrate(model, q, xs + 1e-3, held=[model.names[k] for k in held])   # the poses commanded, 1 mm off
    assert result.misfit_before_m > 1e-3 and result.misfit_after_m < 1e-12, (result.misfit_before_m,
                                                                             result.misfit_after_m)
    assert np.abs(result.theta - truth).max() < 1e-9, np.abs(result.theta - truth).max()
    assert np.abs(result.poses - xs).max() < 1e-9


def test_too_few_readings_and_machines_without_redundancy_refused(model):
    xs = poses_about_home(model.machine, 5, 6)
    q = true_readings(model.machine, np.zeros(model.size), xs)
    with pytest.raises(FieldError, match="5 readings over-measure the platform by 5 for 20 parameters: at least 20"):
        self_calibrate(model, q, xs)
    with pytest.raises(FieldError, match="self-calibration of a planar machine on rails"):
        PlanarRailErrorModel(load_machine("genhexkins").model)
