"""Dynamic model (ARCHI §3.4): energy conservation, statics, inverse/forward identity."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pkm_kinematics import load_machine
from pkm_kinematics.distribution import min_two_norm
from pkm_kinematics.dynamics import DynamicModel, DynamicsParameters, holding_forces
from pkm_kinematics.errors import UnreachablePoseError

CASES = {"archi": ([1.0, -0.4, 0.7], [0.3, -0.2, 1.5]),
         "sliding_star": ([0.05, 0.02, 0.1], [0.2, 0.1, -0.4]),
         "mom3": ([0.05, -0.02, 0.85], [0.2, -0.1, 0.3]),
         "orthoglide": ([0.02, 0.03, 0.01], [0.1, -0.2, 0.15])}


def model(name, friction=None):
    cfg = load_machine(name)
    params = cfg.dynamics
    if friction is not None:
        params = DynamicsParameters(params.drive_mass_kg, params.platform_mass_kg, params.platform_inertia_kgm2,
                                    tuple([friction] * cfg.model.n_legs), params.gravity_m_s2)
    return DynamicModel(cfg.model, params)


@pytest.mark.parametrize("name", list(CASES))
def test_energy_is_conserved_without_friction_and_forces(name):
    """Gravity on, friction and drive forces off: kinetic + potential energy is a
    constant of the motion; any error in A, H (Jdot term) or the potentials breaks it."""
    dyn = model(name, friction=0.0)
    x0, v0 = CASES[name]
    zero = [0.0] * dyn.machine.n_legs

    def rhs(_t, s):
        return [*s[3:], *dyn.forward_dynamics(list(s[:3]), list(s[3:]), zero)]

    sol = solve_ivp(rhs, (0.0, 0.15), [*x0, *v0], rtol=1e-11, atol=1e-12, dense_output=True)
    assert sol.success
    energies = [dyn.energy(list(s[:3]), list(s[3:])) for s in sol.sol(np.linspace(0.0, 0.15, 20)).T]
    kinetic = 0.5 * np.dot(v0, v0) * 5.0
    assert np.ptp(energies) < 1e-6 * max(1.0, kinetic)
    # and the motion is not trivial
    assert np.abs(sol.y[:3, -1] - np.array(x0)).max() > 1e-3


@pytest.mark.parametrize("name", list(CASES))
def test_static_equilibrium_under_gravity(name):
    dyn = model(name)
    x = CASES[name][0]
    jac = dyn.machine.jacobian(x)
    forces = holding_forces(dyn, jac, x)
    np.testing.assert_allclose(dyn.forward_dynamics(x, [0.0, 0.0, 0.0], forces), 0.0, atol=1e-10)
    # the weight must be carried: the drives' wrench has the weight's magnitude
    weight = dyn.params.platform_mass_kg * np.linalg.norm(dyn.params.gravity_m_s2)
    assert np.linalg.norm(jac.T @ forces) >= weight


@pytest.mark.parametrize("name", list(CASES))
def test_inverse_dynamics_inverts_forward_dynamics(name):
    dyn = model(name)
    x, v = CASES[name]
    acc = np.array([0.5, -1.0, 2.0])
    wrench = np.array([10.0, -20.0, 3.0])
    needed = dyn.inverse_dynamics(x, v, acc, wrench)
    forces = min_two_norm(dyn.machine.jacobian(x), needed)
    np.testing.assert_allclose(dyn.forward_dynamics(x, v, forces, wrench), acc, atol=1e-9)
    # friction dissipates: with forces off, dE/dt = -sum k qdot^2 < 0
    fric = model(name)
    h = 1e-6
    zero = [0.0] * fric.machine.n_legs
    a = fric.forward_dynamics(x, v, zero)
    e_minus = fric.energy([xi - h * vi for xi, vi in zip(x, v)], [vi - h * ai for vi, ai in zip(v, a)])
    e_plus = fric.energy([xi + h * vi for xi, vi in zip(x, v)], [vi + h * ai for vi, ai in zip(v, a)])
    qdot = fric.machine.jacobian(x) @ v
    assert (e_plus - e_minus) / (2 * h) == pytest.approx(-np.dot(fric.params.friction_ns_per_m, qdot**2), rel=1e-6)


@pytest.mark.parametrize("name", list(CASES))
def test_velocity_terms_against_the_jacobian_and_its_finite_difference(name):
    """q, J_m, qdot = J_m v and Jdot_m v of the compiled velocity terms against the numpy
    IKM and Jacobian, and Jdot_m v against a central difference of J_m(x + t v) v."""
    machine = model(name).machine
    x, v = CASES[name]
    q, rows, qdot, bias = machine.velocity_terms(x, v)
    jac = machine.jacobian(x)
    np.testing.assert_allclose(q, machine.inverse_kinematics(x, check_limits=False), atol=1e-12)
    np.testing.assert_allclose(rows, jac, atol=1e-12)
    np.testing.assert_allclose(qdot, jac @ v, atol=1e-12)
    h = 1e-6
    jdot_v = (machine.jacobian(np.add(x, np.multiply(h, v))) - machine.jacobian(np.subtract(x, np.multiply(h, v)))) \
        @ v / (2 * h)
    np.testing.assert_allclose(bias, jdot_v, rtol=1e-6, atol=1e-8)
    assert np.abs(bias).max() > 1e-3                    # the test velocity does make a Jdot term


@pytest.mark.parametrize("name", list(CASES))
def test_measured_state_is_the_least_squares_velocity_and_the_model_there(name):
    dyn = model(name)
    x, v = CASES[name]
    jac = dyn.machine.jacobian(x)
    rng = np.random.default_rng(3)
    qdot = jac @ v + (0.0 if jac.shape[0] == 3 else 1e-3 * rng.standard_normal(jac.shape[0]))
    a, h, rows, v_ls = dyn.measured_state(x, qdot.tolist())
    np.testing.assert_allclose(rows, jac, atol=1e-12)
    np.testing.assert_allclose(v_ls, np.linalg.lstsq(jac, qdot, rcond=None)[0], atol=1e-12)
    if jac.shape[0] == 3:
        np.testing.assert_allclose(v_ls, v, atol=1e-12)     # consistent: the velocity itself
    a_ref, h_ref, _, _, _ = dyn.terms(x, v_ls)
    np.testing.assert_allclose(a, a_ref, rtol=1e-14)
    np.testing.assert_allclose(h, h_ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name, far", [("archi", [9.0, 9.0, 0.0]), ("mom3", [5.0, 5.0, 5.0])])
def test_measured_state_names_the_leg_that_cannot_reach(name, far):
    dyn = model(name)
    with pytest.raises(UnreachablePoseError, match=f"unreachable for leg {dyn.machine.leg_names[0]}"):
        dyn.measured_state(far, [0.0] * dyn.machine.n_legs)


@pytest.mark.parametrize("name", ["archi", "mom3"])
def test_wrong_lengths_are_refused_by_name(name):
    dyn = model(name)
    x, v = CASES[name]
    n = dyn.machine.n_legs
    for qdot in ([0.0] * (n - 1), [0.0] * (n + 1)):
        with pytest.raises(ValueError, match=f"drive_velocities: expected {n} values"):
            dyn.measured_state(x, qdot)
    with pytest.raises(ValueError, match="need 3 values each, got 2 and 3"):
        dyn.machine.velocity_terms(x[:2], v)
    with pytest.raises(ValueError, match="need 3 values each, got 3 and 4"):
        dyn.machine.velocity_terms(x, [*v, 0.0])
