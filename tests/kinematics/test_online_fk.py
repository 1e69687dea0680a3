"""On-line forward kinematics by integrating the differential kinematics (Sliding Star
§3.1): against the exact poses of a known path, the explicit Euler form converges with
order 1 in the step and the midpoint rule with order 2 (halving the step divides the
error by ~2 and ~4); a redundant machine's increments are fitted in least squares."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.online_fk import integrate_forward_kinematics

STAR = load_machine("sliding_star").model
MOM3 = load_machine("mom3").model


def path(s):
    """A smooth planar path of Sliding Star: 0.1 m arcs and a 10 deg turn."""
    return np.array([0.1 * math.sin(s), 0.05 * (1 - math.cos(s)), math.radians(10.0) * math.sin(2 * s)])


def final_error(machine, pose_of, steps: int, order: int) -> float:
    x = pose_of(0.0)
    q = machine.inverse_kinematics(x)
    for k in range(1, steps + 1):
        q_next = machine.inverse_kinematics(pose_of(k / steps))
        x = integrate_forward_kinematics(machine, x, q_next - q, order)
        q = q_next
    return float(np.linalg.norm(x - pose_of(1.0)))


@pytest.mark.parametrize("machine, pose_of", [
    (STAR, path),
    (MOM3, lambda s: MOM3.home + np.array([0.05 * math.sin(s), 0.03 * s, -0.04 * s * s])),
])
def test_euler_is_first_order_and_the_midpoint_rule_second_order(machine, pose_of):
    for order, expected in ((1, 2.0), (2, 4.0)):
        coarse, fine = final_error(machine, pose_of, 100, order), final_error(machine, pose_of, 200, order)
        assert coarse / fine == pytest.approx(expected, rel=0.15), (order, coarse, fine)
    assert final_error(machine, pose_of, 200, 2) < 1e-2 * final_error(machine, pose_of, 200, 1)


def test_a_redundant_machines_inconsistent_increments_are_fitted_in_least_squares():
    """Sliding Star's four increments of a pure x motion, plus a part that no motion
    explains (in ker(J^T)): the step is the same as without it."""
    x = path(0.3)
    jac = STAR.jacobian(x)
    dq = jac @ np.array([1e-4, 0.0, 0.0])
    null = np.linalg.svd(jac.T)[2][-1]
    np.testing.assert_allclose(integrate_forward_kinematics(STAR, x, dq + 1e-5 * null, 1),
                               integrate_forward_kinematics(STAR, x, dq, 1), atol=1e-15)
    with pytest.raises(ValueError, match="order: must be 1 or 2"):
        integrate_forward_kinematics(STAR, x, dq, 3)
