"""Task spaces (pkm_kinematics.task_space): a spatial sample's angular velocity and
acceleration in the base frame, against finite differences of the rotation and of
the angular velocity along the motion, and their inverse."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_kinematics.rotations import log_so3, rate_matrix, rate_matrix_derivative, rotation_from_rpy
from pkm_kinematics.task_space import PLANAR, POSITION, SPATIAL, TASK_SPACES, angle_rates, motion_fields

floats = st.floats(-1.0, 1.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(floats, min_size=18, max_size=18))
def test_spatial_motion_fields_against_finite_differences_and_back(values):
    x0 = np.array(values[:6]) * [0.1, 0.1, 0.1, 0.5, 0.5, 0.5] + [0.0, 0.0, 0.5, 0.0, 0.0, 0.0]
    v, a = np.array(values[6:12]), np.array(values[12:18]) * 3.0

    def at(t):
        return x0 + v * t + 0.5 * a * t * t, v + a * t

    x, _ = at(0.0)
    p, q, lin, omega, lin_acc, alpha = motion_fields(SPATIAL, x.tolist(), v.tolist(), a.tolist())
    assert p == tuple(x[:3]) and lin == tuple(v[:3]) and lin_acc == tuple(a[:3])
    h = 1e-6
    (xp, vp), (xm, vm) = at(h), at(-h)
    rotation = [rotation_from_rpy(*y[3:]) for y in (xp, xm)]
    np.testing.assert_allclose(omega, log_so3(rotation[0] @ rotation[1].T) / (2 * h), atol=1e-6)
    omega_p = motion_fields(SPATIAL, xp.tolist(), vp.tolist(), a.tolist())[3]
    omega_m = motion_fields(SPATIAL, xm.tolist(), vm.tolist(), a.tolist())[3]
    np.testing.assert_allclose(alpha, (np.array(omega_p) - np.array(omega_m)) / (2 * h), atol=1e-5)
    rates, accelerations = angle_rates(x[3:], omega, alpha)
    np.testing.assert_allclose(rates, v[3:], atol=1e-12)
    np.testing.assert_allclose(accelerations, a[3:], atol=1e-10)


def test_rate_matrix_derivative_is_the_time_derivative_of_the_rate_matrix():
    b, c, b_rate, c_rate, h = 0.3, -1.1, 0.7, -0.4, 1e-6
    fd = (rate_matrix(0.2, b + h * b_rate, c + h * c_rate) - rate_matrix(0.2, b - h * b_rate, c - h * c_rate)) / (2 * h)
    np.testing.assert_allclose(rate_matrix_derivative(b, c, b_rate, c_rate), fd, atol=1e-8)


def test_planar_and_position_fields_and_the_registry():
    p, q, lin, ang, lin_acc, ang_acc = motion_fields(PLANAR, [1.0, -0.4, 0.3], [0.1, 0.2, 0.5], [1.0, 2.0, 3.0])
    assert p == (1.0, -0.4, 0.0) and ang == (0.0, 0.0, 0.5) and ang_acc == (0.0, 0.0, 3.0)
    assert q == pytest.approx((0.0, 0.0, np.sin(0.15), np.cos(0.15)))
    fields = motion_fields(POSITION, [0.0, 0.1, 0.8], [1.0, 2.0, 3.0], [4.0, 5.0, 6.0])
    assert fields[1] == (0.0, 0.0, 0.0, 1.0) and fields[3] == (0.0, 0.0, 0.0) and fields[4] == (4.0, 5.0, 6.0)
    assert [s.dof for s in TASK_SPACES.values()] == [3, 3, 6]
    assert SPATIAL.describe() == "x, y, z, a, b, c" and PLANAR.words == ("X", "Y", "C")


def test_angle_rates_batch_is_angle_rates_bit_for_bit():
    """The batched form of the per-sample formula (a spatial trajectory's rates as the
    controller reads them back): the same bits as angle_rates sample by sample."""
    import numpy as np
    from pkm_kinematics.task_space import angle_rates, angle_rates_batch
    rng = np.random.default_rng(11)
    angles, omega, alpha = rng.uniform(-1.2, 1.2, (500, 3)), rng.normal(size=(500, 3)), rng.normal(size=(500, 3))
    rates, accelerations = angle_rates_batch(angles, omega, alpha)
    each = [angle_rates(a, w, dw) for a, w, dw in zip(angles, omega, alpha)]
    np.testing.assert_array_equal(rates, [r for r, _ in each])
    np.testing.assert_array_equal(accelerations, [a for _, a in each])
