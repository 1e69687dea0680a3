"""Translational machines (Orthoglide, MoM3 linear Delta) and Orthoglide sizing."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_kinematics import SingularityError, UnreachablePoseError, load_machine
from pkm_kinematics.analysis import orthoglide_model, orthoglide_size, workspace_summary

ORTHO = load_machine("orthoglide").model
DELTA = load_machine("mom3").model


def cube(machine):
    c, half = machine.workspace["center"], machine.workspace["size"] / 2
    return st.tuples(*[st.floats(ci - half, ci + half) for ci in c])


@pytest.mark.parametrize("machine", [ORTHO, DELTA], ids=["orthoglide", "mom3_delta"])
def test_round_trip_over_the_workspace(machine):
    @settings(max_examples=80, deadline=None)
    @given(cube(machine))
    def check(p):
        p = np.array(p)
        rho = machine.inverse_kinematics(p)
        np.testing.assert_allclose(machine.forward_kinematics(rho).pose, p, atol=1e-10)
    check()


@pytest.mark.parametrize("machine,p", [(ORTHO, [0.05, -0.03, 0.08]), (DELTA, [0.1, -0.12, 0.8])])
def test_jacobians_against_finite_differences(machine, p):
    p = np.array(p)
    h = 1e-6
    fd = np.stack([(machine.inverse_kinematics(p + h * e) - machine.inverse_kinematics(p - h * e)) / (2 * h)
                   for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(machine.jacobian(p), fd, atol=1e-8)
    # J_m = B^-1 A (Orthoglide eq. 8)
    np.testing.assert_allclose(np.linalg.solve(machine.serial_jacobian(p), machine.parallel_jacobian(p)),
                               machine.jacobian(p), atol=1e-12)
    v = np.array([0.2, -0.4, 0.3])
    jd_fd = (machine.jacobian(p + h * v) - machine.jacobian(p - h * v)) / (2 * h)
    np.testing.assert_allclose(machine.jacobian_derivative(p, v), jd_fd, atol=1e-7)


def test_orthoglide_isotropic_configuration():
    """Orthoglide §4.2: at the isotropic point J_m is the identity: condition number 1
    and all three velocity transmission factors equal to 1, like a serial PPP machine."""
    np.testing.assert_allclose(ORTHO.jacobian(np.zeros(3)), np.eye(3), atol=1e-15)
    assert ORTHO.condition_number(np.zeros(3)) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(ORTHO.transmission_factors(np.zeros(3)), 1.0, atol=1e-12)
    assert ORTHO.is_isotropic(np.zeros(3))
    assert not ORTHO.is_isotropic(np.array([0.05, 0.0, 0.0]))


@pytest.mark.parametrize("t", [-0.2, -0.1, 0.05, 0.3])
def test_transmission_factors_on_the_diagonal_closed_form(t):
    """On x = y = z (L = 1) J_m = (1 - a) I + a 11^T with a = t / sqrt(1 - 2 t^2), so the
    factors are 1/|1 - a| (twice) and 1/|1 + 2a| (Orthoglide §4.4, step 2)."""
    unit = orthoglide_model(1.0)
    a = t / math.sqrt(1 - 2 * t * t)
    expected = np.sort([1 / abs(1 - a), 1 / abs(1 - a), 1 / abs(1 + 2 * a)])
    np.testing.assert_allclose(unit.transmission_factors(np.full(3, t)), expected, rtol=1e-12)


def test_orthoglide_sizing_reproduces_the_prototype():
    """Orthoglide §4.5: 200 mm cube, 1/2 <= psi <= 2 -> L = 310.9 mm, range 257.1 mm.

    Closed form from the diagonal factors: psi_max = 2 is met at a = 1/2 (t2 = 1/sqrt 6)
    and psi_max = 2 again at a = -1/4 on the other side (t1 = -1/sqrt 18), so
    L = 0.2 / (1/sqrt 6 + 1/sqrt 18).
    """
    s = orthoglide_size(0.2, 0.5, 2.0)
    closed = 0.2 / (1 / math.sqrt(6) + 1 / math.sqrt(18))
    assert s.link_length_m == pytest.approx(closed, rel=1e-10)
    assert s.link_length_m == pytest.approx(0.3109, rel=2e-3)       # paper, 0.1 % apart
    assert s.actuator_range_m == pytest.approx(0.2571, rel=2e-3)
    assert s.range_ratio == pytest.approx(1.28, abs=0.01)
    # the bounds hold on the whole cube (the paper's step-1 postulate, checked numerically)
    assert s.psi_range_on_cube[0] >= 0.5 - 1e-9 and s.psi_range_on_cube[1] <= 2.0 + 1e-9
    with pytest.raises(ValueError, match="psi bounds"):
        orthoglide_size(0.2, 1.5, 2.0)


def test_configured_orthoglide_meets_its_bounds():
    summary = workspace_summary(ORTHO, points_per_axis=9)
    assert summary.reachable_fraction == 1.0
    lo, hi = ORTHO.transmission_bounds
    assert lo - 1e-4 <= summary.transmission_min and summary.transmission_max <= hi + 1e-4


def test_batch_and_errors():
    rng = np.random.default_rng(0)
    c, half = DELTA.workspace["center"], DELTA.workspace["size"] / 2
    p = c + rng.uniform(-half, half, (300, 3))
    rho, ok = DELTA.inverse_kinematics_batch(p)
    fk, ok2 = DELTA.forward_kinematics_batch(rho)
    assert ok.all() and ok2.all()
    np.testing.assert_allclose(fk, p, atol=1e-10)
    with pytest.raises(UnreachablePoseError, match="leg q1"):
        DELTA.inverse_kinematics([0.0, -0.9, 0.8])
    with pytest.raises(UnreachablePoseError, match="cannot be assembled"):
        DELTA.forward_kinematics_floats([1.2, 3.0, 1.2])
    failed = DELTA.forward_kinematics([1.2, 3.0, 1.2])          # the result form: no pose, the reason
    assert not failed.converged and np.isnan(failed.pose).all() and "cannot be assembled" in failed.reason
    with pytest.raises(ValueError, match="position: contains NaN"):
        ORTHO.inverse_kinematics([0.0, np.nan, 0.0])


@pytest.mark.parametrize("machine", [ORTHO, DELTA], ids=["orthoglide", "mom3_delta"])
def test_forward_kinematics_keeps_every_leg_on_its_branch(machine):
    """Joint space -> FK -> IK: inside the joint limits, either the round trip closes
    or FK refuses (a leg would have to flip to its other branch); never a wrong point."""
    rng = np.random.default_rng(4)
    rho = rng.uniform(machine.joint_lower, machine.joint_upper, (20000, 3))
    p, ok = machine.forward_kinematics_batch(rho)
    back, reach = machine.inverse_kinematics_batch(np.where(ok[:, None], p, machine.home))
    np.testing.assert_allclose(back[ok], rho[ok], atol=1e-9)
    refused = 0
    for k in range(0, 20000, 50):
        try:
            np.testing.assert_allclose(machine.inverse_kinematics(machine.forward_kinematics_floats(rho[k]), False),
                                       rho[k], atol=1e-9)
            assert ok[k]
        except UnreachablePoseError:
            assert not ok[k]
            refused += 1
    if machine is DELTA:       # 0.1-0.2 % of the joint box needs a flipped leg
        assert (~ok).sum() > 0


@pytest.mark.parametrize("machine", [ORTHO, DELTA], ids=["orthoglide", "mom3_delta"])
def test_the_per_cycle_forward_kinematics_is_forward_kinematics(machine):
    rho = machine.inverse_kinematics(machine.home + [0.01, -0.02, 0.015]).tolist()
    np.testing.assert_array_equal(machine.forward_kinematics_floats(rho), machine.forward_kinematics(rho).pose)
    with pytest.raises(ValueError, match="rho: expected 3 actuator positions, got 2"):
        machine.forward_kinematics_floats(rho[:2])
    with pytest.raises(SingularityError, match="collinear"):
        ORTHO.forward_kinematics_floats([0.0, 0.0, -0.3])


def test_singular_and_malformed_inputs_raise_clear_errors():
    with pytest.raises(SingularityError, match="collinear"):
        ORTHO.forward_kinematics_floats([0.0, 0.0, -0.3])
    # a leg perpendicular to its rail: |p_y, p_z| = L, so rho1 = p_x
    p = np.array([0.0, ORTHO.legs[0].link_length, 0.0])
    with pytest.raises(SingularityError, match="leg rho1 is perpendicular to its rail"):
        ORTHO.condition_number(p)
    np.testing.assert_allclose(ORTHO.jacobian([0.01, 0.02, 0.03], q=list(ORTHO.inverse_kinematics([0.01, 0.02, 0.03]))),
                               ORTHO.jacobian([0.01, 0.02, 0.03]))
    with pytest.raises(ValueError, match="velocity: expected shape 3"):
        ORTHO.jacobian_derivative([0.0, 0.0, 0.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="velocity: contains NaN"):
        ORTHO.jacobian_derivative([0.0, 0.0, 0.0], [1.0, np.nan, 0.0])
