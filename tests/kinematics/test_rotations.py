"""SO(3) helpers: exponential/logarithm, RPY and quaternions against closed forms."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_kinematics.rotations import (exp_so3, log_so3, mul3, quaternion_from_rotation, rotation_about_z,
                                      rotation_from_quaternion, rotation_from_rpy, rpy_from_rotation, skew)

vectors = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)


@settings(max_examples=100, deadline=None)
@given(vectors)
def test_exp_is_a_rotation_and_log_inverts_it(w):
    r = exp_so3(w)
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r @ w, w, atol=1e-12)              # the axis is fixed
    if np.linalg.norm(w) < math.pi - 1e-3:
        np.testing.assert_allclose(log_so3(r), w, atol=1e-9)


def test_exp_matches_the_matrix_exponential_series():
    w = np.array([0.3, -0.2, 0.5])
    k = skew(w)
    series, term = np.eye(3), np.eye(3)
    for n in range(1, 30):
        term = term @ k / n
        series = series + term
    np.testing.assert_allclose(exp_so3(w), series, atol=1e-14)
    np.testing.assert_allclose(exp_so3([1e-10, 0.0, 0.0]), np.eye(3) + skew([1e-10, 0.0, 0.0]), atol=1e-20)
    np.testing.assert_allclose(np.array(mul3(exp_so3(w).ravel(), exp_so3(-w).ravel())).reshape(3, 3),
                               np.eye(3), atol=1e-14)


@settings(max_examples=100, deadline=None)
@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_rpy_and_quaternion_round_trips(roll, pitch, yaw):
    r = rotation_from_rpy(roll, pitch, yaw)
    np.testing.assert_allclose(r, rotation_about_z(yaw) @ exp_so3([0, pitch, 0]) @ exp_so3([roll, 0, 0]),
                               atol=1e-12)
    np.testing.assert_allclose(rpy_from_rotation(r), [roll, pitch, yaw], atol=1e-9)
    q = quaternion_from_rotation(r)
    assert q[3] >= 0.0 and np.linalg.norm(q) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation_from_quaternion(q), r, atol=1e-12)
    # the quaternion's axis-angle is the rotation vector
    angle = 2.0 * math.atan2(np.linalg.norm(q[:3]), q[3])
    if 1e-6 < angle < math.pi - 1e-5:          # at pi log_so3's axis is good to ~sqrt(eps), its sign free
        np.testing.assert_allclose(q[:3] / np.linalg.norm(q[:3]) * angle, log_so3(r), atol=1e-8)


def test_quaternion_validation():
    with pytest.raises(ValueError, match="quaternion: must be finite and non-zero"):
        rotation_from_quaternion([0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(rotation_from_quaternion([0, 0, 0, 2.0]), np.eye(3))


def test_the_compiled_rotation_check_finds_the_first_improper_row_as_numpy_does():
    """``first_improper_rotation_kernel`` against numpy's R^T R and det on rotations,
    a reflection, a scaled rotation, a slightly skewed one and a NaN."""
    from pkm_kinematics.rotations import first_improper_rotation_kernel
    rng = np.random.default_rng(2)
    good = np.array([exp_so3(w) for w in rng.uniform(-3.0, 3.0, (20, 3))])
    bad = [np.diag([1.0, 1.0, -1.0]), 1.01 * np.eye(3), exp_so3([0.1, 0.2, 0.3]) + 2e-6 * np.eye(3)[[1, 2, 0]],
           np.full((3, 3), np.nan)]

    def numpy_first(rotations):
        distortion = np.abs(np.einsum("nji,njk->nik", rotations, rotations) - np.eye(3)).max(axis=(1, 2))
        with np.errstate(invalid="ignore"):
            flagged = ~(distortion <= 1e-6) | ~(np.linalg.det(rotations) > 0.0)
        return int(np.argmax(flagged)) if flagged.any() else -1
    assert first_improper_rotation_kernel(good.reshape(-1, 9), 1e-6) == -1
    for k, b in enumerate(bad):
        rotations = np.concatenate([good[:5 + k], [b], good[5 + k:]])
        assert first_improper_rotation_kernel(rotations.reshape(-1, 9), 1e-6) == numpy_first(rotations) == 5 + k


def test_unwrap_to_moves_by_whole_turns_to_the_nearest_and_the_kernel_agrees():
    import math

    from pkm_kinematics.rotations import unwrap_to, unwrap_to_kernel
    for angle, reference, want in ((0.1, 2 * math.pi, 0.1 + 2 * math.pi), (3.0, -3.0, 3.0 - 2 * math.pi),
                                   (-0.2, 0.0, -0.2), (1.0, 13.0, 1.0 + 4 * math.pi)):
        got = unwrap_to(angle, reference)
        assert got == want and abs(got - reference) <= math.pi
        assert unwrap_to_kernel(angle, reference) == got            # bit for bit, compiled


def test_the_yaw_of_a_quaternion_is_the_rotations_and_the_batched_form_agrees_to_an_ulp():
    import math

    import numpy as np

    from pkm_kinematics.rotations import (quaternion_from_rotation, rotation_about_z, yaw_of_quaternion,
                                          yaw_of_quaternions)
    yaws = np.linspace(-math.pi + 1e-9, math.pi, 101)
    quaternions = np.array([quaternion_from_rotation(rotation_about_z(a)) for a in yaws])
    scalar = np.array([yaw_of_quaternion(*q) for q in quaternions.tolist()])
    np.testing.assert_allclose(scalar, yaws, atol=1e-12)
    # numpy's arctan2 and libm's atan2 differ in the last bit for some inputs
    np.testing.assert_array_max_ulp(yaw_of_quaternions(quaternions), scalar, maxulp=1)


def test_wrap_angle_is_in_minus_pi_to_pi_and_keeps_an_angle_inside_as_it_is():
    import math

    import numpy as np

    from pkm_kinematics.rotations import wrap_angle, wrap_angles
    angles = [3.0 * math.pi, -3.0 * math.pi, math.pi, -math.pi, 0.1, -0.5, 7.0, -7.0, 1e-9]
    wrapped = [wrap_angle(a) for a in angles]
    assert all(-math.pi < w <= math.pi for w in wrapped), wrapped
    assert wrapped[2] == math.pi and wrapped[3] == math.pi                 # (-pi, pi]: -pi is pi
    assert wrapped[4:6] == [0.1, -0.5] and wrapped[8] == 1e-9              # inside: unchanged, bit for bit
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles), atol=1e-12)
    assert wrap_angles(np.array(angles)).tolist() == wrapped                # the batched form: the same
