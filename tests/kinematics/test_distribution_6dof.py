"""The force distributions for n x 6 Jacobians (issue 23): the hexapods' J_m^T maps
strut forces to the platform wrench; the 6-strut hexapod has one solution, the
8-strut one a 2-dimensional null space. References: J^T f = F, the optimality
conditions of each norm, a grid search over the null space, and the 4 x 3 closed
forms where both apply."""

import numpy as np
import pytest

from pkm_kinematics import DistributionError, load_machine
from pkm_kinematics import distribution as fd

WRENCH = np.array([120.0, -80.0, 400.0, 15.0, -20.0, 8.0])       # N, N m


def jacobian(name):
    machine = load_machine(name).model
    return machine.jacobian(machine.home + np.array([0.02, -0.01, 0.01, 0.04, -0.03, 0.1]))


@pytest.mark.parametrize("method", ["pseudo_inverse", "inf_norm", "p_norm"])
def test_the_six_strut_hexapod_has_one_distribution(method):
    jac = jacobian("genhexkins")
    forces = fd.distribute(method, jac, WRENCH)
    np.testing.assert_allclose(forces, np.linalg.solve(jac.T, WRENCH), rtol=1e-9, atol=1e-9)
    with pytest.raises(DistributionError, match="prestress: no internal force exists with 6 drives for 6 DOF"):
        fd.distribute(method, jac, WRENCH, prestress_n=100.0, prestress_direction=np.ones(6))


def test_the_redundant_hexapod_distributions_meet_their_optimality_conditions():
    jac = jacobian("hexapod8")
    basis = fd.null_space(jac)
    assert basis.shape == (8, 2)
    two = fd.min_two_norm(jac, WRENCH)
    np.testing.assert_allclose(jac.T @ two, WRENCH, rtol=1e-10)
    np.testing.assert_allclose(basis.T @ two, 0.0, atol=1e-9)                    # no internal force
    inf = fd.min_inf_norm(jac, WRENCH)
    np.testing.assert_allclose(jac.T @ inf, WRENCH, rtol=1e-8, atol=1e-8)
    # a grid over the null space: nothing beats the LP's peak
    z = np.linspace(-600.0, 600.0, 241)
    grid = two[None, None, :] + z[:, None, None] * basis[:, 0] + z[None, :, None] * basis[:, 1]
    best = np.abs(grid).max(axis=2).min()
    peak = np.abs(inf).max()
    assert peak <= best + 1e-6 and best - peak < 5.0                            # 5 N: the grid's spacing
    for p in (4.0, 8.0):
        forces = fd.min_p_norm(jac, WRENCH, p)
        np.testing.assert_allclose(jac.T @ forces, WRENCH, rtol=1e-9, atol=1e-9)
        gradient = basis.T @ (np.abs(forces) ** (p - 1.0) * np.sign(forces))   # stationary along ker(J^T)
        assert np.abs(gradient).max() < 1e-6 * np.sum(np.abs(forces) ** (p - 1.0))
        assert np.abs(forces).max() <= np.abs(two).max() + 1e-9 and np.abs(forces).max() >= peak - 1e-9


def test_prestress_along_a_chosen_direction_of_a_two_dimensional_null_space():
    jac = jacobian("hexapod8")
    base = fd.min_two_norm(jac, WRENCH)
    preload = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0])            # pairs against each other
    forces = fd.distribute("pseudo_inverse", jac, WRENCH, prestress_n=200.0, prestress_direction=preload)
    internal = forces - base
    np.testing.assert_allclose(jac.T @ forces, WRENCH, rtol=1e-10)                # the wrench unchanged
    assert np.linalg.norm(internal) == pytest.approx(200.0, rel=1e-12)
    basis = fd.null_space(jac)
    expected = basis @ (basis.T @ preload)
    np.testing.assert_allclose(internal, 200.0 * expected / np.linalg.norm(expected), atol=1e-9)
    with pytest.raises(DistributionError, match="direction has no internal part"):
        fd.add_prestress(jac, base, 100.0, direction=jac[:, 0])                  # in the range of J
    with pytest.raises(ValueError, match=r"prestress: the 8 x 6 Jacobian's internal forces are not one line"):
        fd.add_prestress(jac, base, 100.0)


def test_the_direction_form_agrees_with_the_closed_form_on_a_four_by_three_jacobian():
    archi = load_machine("archi").model
    jac = archi.jacobian(archi.home)
    line = fd.null_direction(jac)
    np.testing.assert_allclose(fd.prestress_direction(jac, line + 0.3 * jac[:, 0]), line, atol=1e-12)
