"""Kinematic calibration of a strut machine with an external instrument (a laser
tracker reading the tool point): the identification Jacobian against central
differences of the model's own predictions; what a point measurement cannot identify
(the instrument's frame against the base joints: 6; the platform's rotation about the
measured point: 3) named; injected errors identified from noise-free readings to 1e-9
and from noisy ones within their predicted standard deviations (a chi-square over
seeds, in the metric of its predicted covariance); bad input refused naming it."""

import numpy as np
import pytest

from pkm_calibration.identify import identifiability, identify
from pkm_calibration.strut_errors import StrutErrorModel
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError

TOOL = (0.0, 0.0, -0.05)


@pytest.fixture(scope="module")
def model():
    return StrutErrorModel(load_machine("genhexkins").model, TOOL)


def poses(machine, n, seed):
    """n poses drawn uniformly in the workspace box and its rotation ranges."""
    rng = np.random.default_rng(seed)
    ws = machine.workspace
    lo = np.concatenate((ws["center"] - ws["half_size"], -np.radians(ws["abc_half_range_deg"])))
    hi = np.concatenate((ws["center"] + ws["half_size"], np.radians(ws["abc_half_range_deg"])))
    return rng.uniform(lo, hi, size=(n, 6))


def readings_of(model, theta_true, xs):
    """What the real machine (``theta_true``) reads at the poses xs: its encoders, and
    the tracker's point (noise-free)."""
    real = model.machine_for(theta_true)
    _, _, dz, ds, _, _ = model.split(theta_true)
    lengths, _ = real.inverse_kinematics_batch(xs)
    q = (lengths - dz) / (1.0 + ds)                 # l = q + z + s q
    return q, model.predict(theta_true, q, guesses=xs).y


def injected(model, seed, held=()):
    rng = np.random.default_rng(seed)
    theta = np.concatenate((rng.normal(0, 1e-3, 6 * 3 * 2), rng.normal(0, 5e-4, 6), rng.normal(0, 1e-3, 6),
                            rng.normal(0, 2e-3, 3), rng.normal(0, 5e-3, 3)))
    theta[list(held)] = 0.0
    return theta


def test_the_identification_jacobian_is_the_models_derivative(model):
    xs = poses(model.machine, 12, 1)
    theta = injected(model, 2)
    q, _ = readings_of(model, theta, xs)
    jac = model.jacobian(theta, q)
    fd = np.zeros_like(jac)
    h = 1e-7
    for j in range(model.size):
        d = np.zeros(model.size)
        d[j] = h
        ahead, behind = (model.predict(theta + s * d, q, guesses=xs).y for s in (1.0, -1.0))
        fd[:, j] = (ahead - behind).ravel() / (2 * h)
    assert np.abs(jac - fd).max() < 1e-7, np.abs(jac - fd).max()


def test_a_point_measurement_cannot_identify_nine_combinations(model):
    xs = poses(model.machine, 40, 3)
    q, _ = readings_of(model, np.zeros(model.size), xs)
    which = identifiability(model.jacobian(np.zeros(model.size), q), model.names)
    assert len(which.identified) == model.size - 9, which.describe()
    # the frame's six against the base joints', the platform's three rotations about the tool point
    assert len(which.held) == 9 and "held at nominal" in which.describe()


def test_injected_errors_identified_from_noise_free_readings(model):
    xs = poses(model.machine, 40, 4)
    q0, _ = readings_of(model, np.zeros(model.size), xs)
    held = identifiability(model.jacobian(np.zeros(model.size), q0), model.names).held
    truth = injected(model, 5, held)
    q, y = readings_of(model, truth, xs)
    result = identify(model, q, y, sigma_m=1e-6, guesses=xs, held=[model.names[k] for k in held])
    assert result.rms_before_m > 1e-4 and result.rms_after_m < 1e-11, (result.rms_before_m, result.rms_after_m)
    assert np.abs(result.theta - truth).max() < 1e-9, np.abs(result.theta - truth).max()


def test_noisy_identification_within_its_predicted_uncertainty(model):
    """sigma 10 um on the tracker: each seed's error in the metric of its predicted
    covariance, e^T C^-1 e, is chi-square with 45 degrees of freedom; over 8 seeds their
    sum has mean 360 and standard deviation 26.8 (4 of them allowed)."""
    xs = poses(model.machine, 60, 6)
    q0, _ = readings_of(model, np.zeros(model.size), xs)
    held = identifiability(model.jacobian(np.zeros(model.size), q0), model.names).held
    sigma = 1e-5
    total, dof = 0.0, 0
    for seed in range(8):
        truth = injected(model, 100 + seed, held)
        q, y = readings_of(model, truth, xs)
        noisy = y + np.random.default_rng(200 + seed).normal(0.0, sigma, y.shape)
        result = identify(model, q, noisy, sigma_m=sigma, guesses=xs, held=[model.names[k] for k in held])
        free = list(result.identifiable.identified)
        error = result.theta[free] - truth[free]
        total += float(error @ np.linalg.solve(result.covariance, error))
        dof += len(free)
        assert result.rms_after_m < sigma < 0.05 * result.rms_before_m, (result.rms_after_m, result.rms_before_m)
    assert abs(total - dof) < 4 * np.sqrt(2 * dof), (total, dof)


def test_bad_input_refused_naming_it(model):
    xs = poses(model.machine, 5, 7)
    q, y = readings_of(model, np.zeros(model.size), xs)
    with pytest.raises(FieldError, match="poses: 15 measurements for 54 parameters: too few poses"):
        identify(model, q, y, sigma_m=1e-5)
    with pytest.raises(FieldError, match="measured: expected one point"):
        identify(model, q, y[:3], sigma_m=1e-5)
    with pytest.raises(FieldError, match="sigma_m"):
        identify(model, q, y, sigma_m=0.0)
