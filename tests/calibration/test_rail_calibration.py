"""Machines on rails with an instrument (rail_errors.RailErrorModel, calibrate_rails):
the closures' and the instrument's Jacobians against central differences on ARCHI
(planar) and MoM3's Delta (translating); readings made by the as-built machine's own
inverse kinematics (machine_for: rails.RailMachine.with_legs, a second path to the
bars); injected errors recovered from noise-free readings to 1e-9, and from noisy ones
within their predicted covariance (chi-square over seeds); what a point cannot see,
named."""

import numpy as np
import pytest
from finite_differences import central_differences, worst_column      # tests/finite_differences.py

from pkm_calibration.poses import candidate_poses
from pkm_calibration.rail_errors import RailErrorModel
from pkm_calibration.self_calibration import calibrate_rails
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError

TOOL = (0.05, -0.02, 0.1)


def setup(name, count, seed):
    machine = load_machine(name).model
    model = RailErrorModel(machine, instrument=True, tool=TOOL)
    poses = candidate_poses(machine, count, seed)
    return model, poses


def readings_of(model, theta, poses):
    q, ok = model.machine_for(theta).inverse_kinematics_batch(poses)
    assert ok.all()
    return q, model.points(theta, poses)


@pytest.mark.parametrize("name", ["archi", "mom3"])
def test_the_jacobians_are_their_derivatives(name):
    model, poses = setup(name, 6, 1)
    theta = np.random.default_rng(2).normal(0.0, 1e-3, model.size)
    q, _ = readings_of(model, theta, poses)
    assert np.abs(model.residuals(theta, poses, q)).max() < 1e-12       # machine_for's bars are the model's
    d_pose, d_theta = model.jacobian(theta, poses, q)
    y_pose, y_theta = model.point_jacobian(theta, poses)
    for f, x, analytic in ((lambda t: model.residuals(t, poses, q), theta, d_theta),
                           (lambda t: model.points(t, poses), theta, y_theta)):
        error, j = worst_column(central_differences(f, x), analytic)
        assert error < 1e-7, model.names[j]
    for f, analytic in ((lambda x: model.residuals(theta, x, q), d_pose), (lambda x: model.points(theta, x), y_pose)):
        error, j = worst_column(central_differences(f, poses), analytic)
        assert error < 1e-7, j


@pytest.mark.parametrize("name, identified", [("archi", 20), ("mom3", 14)])
def test_injected_errors_recovered_from_noise_free_readings(name, identified):
    model, poses = setup(name, 40, 3)
    q0, _ = readings_of(model, np.zeros(model.size), poses)
    which = model.identifiability(poses, q0)
    assert len(which.identified) == identified, which.describe()
    truth = np.random.default_rng(4).normal(0.0, 5e-4, model.size)
    truth[list(which.held)] = 0.0
    q, y = readings_of(model, truth, poses)
    guesses = poses + np.array([1e-3, -1e-3, 1e-3 if name == "mom3" else 1e-2])
    result = calibrate_rails(model, q, guesses, y, held=[model.names[k] for k in which.held])
    assert result.misfit_before_m > 1e-4 and result.misfit_after_m < 1e-12, (result.misfit_before_m,
                                                                             result.misfit_after_m)
    assert np.abs(result.theta - truth).max() < 1e-9, np.abs(result.theta - truth).max()


def test_noisy_identification_within_its_predicted_covariance():
    """MoM3 with the Gough as instrument (2 um) and 1 um encoder counts: each seed's
    e^T C^-1 e is chi-square with 14 degrees of freedom; over 10 seeds their sum has
    mean 140 and standard deviation 16.7 (4 of them allowed)."""
    model, poses = setup("mom3", 40, 5)
    q0, _ = readings_of(model, np.zeros(model.size), poses)
    held = [model.names[k] for k in model.identifiability(poses, q0).held]
    total, dof = 0.0, 0
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        truth = rng.normal(0.0, 5e-4, model.size)
        truth[[model.names.index(n) for n in held]] = 0.0
        q, y = readings_of(model, truth, poses)
        q = np.round(q * 1e6) / 1e6                                   # the encoders' 1 um count
        y = y + rng.normal(0.0, 2e-6, y.shape)
        result = calibrate_rails(model, q, poses, y, point_sigma_m=2e-6, held=held)
        free = list(result.identifiable.identified)
        error = result.theta[free] - truth[free]
        total += float(error @ np.linalg.solve(result.covariance, error))
        dof += len(free)
    assert abs(total - dof) < 4 * np.sqrt(2 * dof), (total, dof)


def test_bad_input_refused_naming_it():
    model, poses = setup("mom3", 8, 6)          # 3 closures and 3 coordinates a reading, 3 pose unknowns
    q, y = readings_of(model, np.zeros(model.size), poses)
    with pytest.raises(FieldError, match="^points: expected one point"):
        calibrate_rails(model, q, poses, y[:4])
    with pytest.raises(FieldError, match="5 readings over-measure the platform by 15 for 21 parameters: at least 7"):
        calibrate_rails(model, q[:5], poses[:5], y[:5])
    with pytest.raises(FieldError, match="^machine: genhexkins: the rail error model is for machines on rails"):
        RailErrorModel(load_machine("genhexkins").model)
