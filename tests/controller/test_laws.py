"""Control-law building blocks against independent references (numpy, finite
differences, closed-form identities) and the trajectory reference."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.distribution import gram_condition
from pkm_kinematics.rotations import exp_so3
from pkm_controller.laws import (DIST_INF_NORM, DIST_PSEUDO_INVERSE, FOLLOWING_ERROR_M,
                                 FOLLOWING_ERROR_RAD, JOINT_LIMIT, LAW_CARTESIAN_PID, LAW_COMPUTED_TORQUE,
                                 LAW_VELOCITY_CASCADE, LIMITS_OK, NUMPY_DISTRIBUTION, SINGULARITY_MARGIN,
                                 WORKSPACE_LIMIT, WRENCH_NOT_FINITE, Gains, cartesian_command_kernel,
                                 clamp_forces_kernel, kernel_settings, limits_kernel, pose_error,
                                 project_to_range, tool_pose_floats, wrap_angle)
from pkm_controller.sensor_space import SensorSpaceFeedback
from pkm_controller.reference import Reference, unwrap_angles

ARCHI = load_machine("archi")
MOM3 = load_machine("mom3")
RNG = np.random.default_rng(7)


@settings(max_examples=60, deadline=None)
@given(st.integers(3, 6), st.integers(0, 10_000))
def test_gram_condition_equals_numpy_cond(n, seed):
    jac = np.random.default_rng(seed).normal(size=(n, 3))
    assert gram_condition(jac.tolist()) == pytest.approx(np.linalg.cond(jac), rel=1e-7)


def test_gram_condition_of_singular_and_isotropic_matrices():
    assert gram_condition([(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 1.0, 0.0)]) == math.inf
    assert gram_condition([(2.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 2.0)]) == 1.0


def test_projection_keeps_the_wrench_and_removes_the_internal_force():
    """Sliding Star eq. 6-8: J^T n = J^T n_d, and n has no component in ker(J^T)."""
    jac = ARCHI.model.jacobian([1.0, -0.4, 0.9])
    n_d = [300.0, -120.0, 45.0, 800.0]
    n = np.array(project_to_range(jac.tolist(), n_d))
    np.testing.assert_allclose(jac.T @ n, jac.T @ np.array(n_d), atol=1e-9)
    null = np.linalg.svd(jac.T)[2][-1]
    assert abs(null @ n) < 1e-9
    assert abs(null @ np.array(n_d)) > 100.0          # there was fighting to remove


def test_angle_helpers():
    assert wrap_angle(3.0 * math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-0.5) == -0.5
    assert pose_error([0, 0, math.pi - 0.1], [0, 0, -math.pi + 0.1], True)[2] == pytest.approx(-0.2)
    assert pose_error([0, 0, 5.0], [0, 0, 1.0], False)[2] == 4.0
    assert unwrap_angles([3.0, -3.0, -2.0]) == pytest.approx([3.0, 2 * math.pi - 3.0, 2 * math.pi - 2.0])


def test_cascade_gains_match_the_pd_characteristic():
    """Inner velocity loop kv and outer kp give s^2 + kv s + kv kp_o = s^2 + 2 zeta w s + w^2."""
    g = Gains(2 * math.pi * 20, 0.8, 0.05)
    assert g.kd * g.outer_kp == pytest.approx(g.kp)
    assert g.ki == pytest.approx(g.kp / 0.05)
    assert Gains(10.0, 1.0, 0.0).ki == 0.0


# ------------------------------------------------ the compiled Cartesian cycle
JAC4 = ARCHI.model.jacobian([1.0, -0.4, 0.9])
JOINT_BOX = np.array([[-1.0, 1.0]] * 4)
TASK_BOX = np.array([[0.0, 2.0], [-1.0, 1.0]])


def _limits(q=(0.0, 0.1, -0.2, 0.3), measured=(1.0, 0.0, 0.5), error=(1e-4, -2e-4, 1e-3), rows=JAC4,
            planar=True):
    return limits_kernel(np.array(q), rows, tuple(measured), tuple(error), (JOINT_BOX, TASK_BOX),
                         kernel_settings(100.0, 0.01, 0.05, 1e6), planar)


def test_limits_kernel_reports_the_first_limit_violated():
    code, _, trans = _limits()
    assert code == LIMITS_OK and trans == pytest.approx(math.hypot(1e-4, 2e-4))
    assert _limits(q=(0.0, 1.5, -0.2, math.nan))[:2] == (JOINT_LIMIT, 1)
    assert _limits(q=(0.0, 0.1, math.nan, 0.3))[:2] == (JOINT_LIMIT, 2)         # NaN is outside every range
    assert _limits(measured=(1.0, -1.2, 9.0)) == (WORKSPACE_LIMIT, 1, -1.2)    # theta has no box (planar)
    singular = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [2.0, 1.0, 0.0]])
    assert _limits(rows=singular)[0] == SINGULARITY_MARGIN
    code, _, value = _limits(error=(0.008, 0.008, 0.0))
    assert code == FOLLOWING_ERROR_M and value == pytest.approx(0.008 * math.sqrt(2.0))
    assert _limits(error=(0.008, 0.0, 0.0), planar=False)[0] == LIMITS_OK
    assert _limits(error=(0.008, 0.0, 0.008), planar=False)[0] == FOLLOWING_ERROR_M     # z counts in 3-D
    assert _limits(error=(0.0, 0.0, -0.06)) == (FOLLOWING_ERROR_RAD, 2, 0.06)


def test_clamp_forces_kernel():
    clamped, saturated, peak, finite = clamp_forces_kernel(np.array([100.0, -2500.0, 2000.0, 3000.0]), 2000.0)
    assert finite and saturated == 2 and peak == 2000.0
    np.testing.assert_array_equal(clamped, [100.0, -2000.0, 2000.0, 2000.0])
    assert not clamp_forces_kernel(np.array([1.0, math.inf, -math.inf]), 10.0)[3]


def _command(law, distribution=DIST_PSEUDO_INVERSE, integrate=True, rows=JAC4, limit=1e6, h_nan=False):
    rng = np.random.default_rng(0)
    m = rng.normal(size=(3, 3))
    a_model = m @ m.T + 3.0 * np.eye(3)
    h, v_d, v, a_d = (rng.normal(size=3) for _ in range(4))
    h[0] = math.nan if h_nan else h[0]
    error = 1e-3 * rng.normal(size=3)
    gains = np.abs(rng.normal(size=(4, 3))) * [[1e4], [1e2], [1e5], [10.0]]
    integral = rng.normal(size=3)
    task = ((1.0, 0.0, 0.0), tuple(error), tuple(v_d), tuple(v), tuple(a_d))     # laws.TASK_* rows
    out = cartesian_command_kernel(np.zeros(rows.shape[0]), rows, task, (tuple(map(tuple, a_model)), tuple(h)),
                                   tuple(integral), integrate, 1e-3,
                                   (np.array([[-1.0, 1.0]] * rows.shape[0]), TASK_BOX), gains,
                                   kernel_settings(1e3, 1.0, 1.0, limit), (1, law, distribution))
    i_ref = integral + gains[2] * error * 1e-3 if integrate else integral
    kp, kd, mass = gains[0], gains[1], gains[3]
    if law == LAW_CARTESIAN_PID:        # Sliding Star eq. 9 with the mass feed-forward
        wrench = kp * error + kd * (v_d - v) + i_ref + mass * a_d
    elif law == LAW_COMPUTED_TORQUE:    # ARCHI §4.2
        wrench = a_model @ (a_d + kd * (v_d - v) + kp * error + i_ref) + h
    else:                               # MoM3 §6.1 cascade: v_c = v_d + Kp e + I
        wrench = a_model @ (a_d + kd * (v_d + kp * error + i_ref - v)) + h
    return out, i_ref, wrench


@pytest.mark.parametrize("law", [LAW_CARTESIAN_PID, LAW_COMPUTED_TORQUE, LAW_VELOCITY_CASCADE])
@pytest.mark.parametrize("integrate", [True, False])
def test_cartesian_command_kernel_laws_against_numpy(law, integrate):
    (code, _, _, integral, wrench, forces, saturated, peak), i_ref, w_ref = _command(law, integrate=integrate)
    assert code == LIMITS_OK and saturated == 0
    np.testing.assert_allclose(integral, i_ref, rtol=1e-14)
    np.testing.assert_allclose(wrench, w_ref, rtol=1e-12)
    np.testing.assert_allclose(forces, np.linalg.pinv(JAC4.T) @ w_ref, rtol=1e-9)    # least 2-norm forces
    assert peak == pytest.approx(np.abs(forces).max())


def test_cartesian_command_kernel_distributions_and_clamp():
    (_, _, _, _, _, f2, _, _), _, wrench = _command(LAW_COMPUTED_TORQUE, DIST_PSEUDO_INVERSE)
    (code, _, _, _, _, finf, _, _), _, _ = _command(LAW_COMPUTED_TORQUE, DIST_INF_NORM)
    assert code == LIMITS_OK
    np.testing.assert_allclose(JAC4.T @ finf, wrench, rtol=1e-9)
    assert np.abs(finf).max() < np.abs(f2).max()                   # the least peak (ARCHI §4.4.2)
    assert len(_command(LAW_COMPUTED_TORQUE, NUMPY_DISTRIBUTION)[0][5]) == 0   # the caller distributes
    limit = 0.5 * np.abs(f2).max()
    (code, _, _, _, _, clamped, saturated, peak), _, _ = _command(LAW_COMPUTED_TORQUE, limit=limit)
    assert code == LIMITS_OK and saturated == np.sum(np.abs(f2) > limit) >= 1 and peak == limit
    np.testing.assert_allclose(clamped, np.clip(f2, -limit, limit))


def test_cartesian_command_kernel_reports_instead_of_commanding():
    singular = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    out, _, _ = _command(LAW_COMPUTED_TORQUE, rows=singular)
    assert out[0] == SINGULARITY_MARGIN and len(out[5]) == 0
    out, _, _ = _command(LAW_COMPUTED_TORQUE, h_nan=True)
    assert out[0] == WRENCH_NOT_FINITE and math.isnan(out[4][0]) and len(out[5]) == 0
    rng_rows = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    out, _, _ = _command(LAW_COMPUTED_TORQUE, DIST_INF_NORM, rows=rng_rows)
    assert out[0] == LIMITS_OK           # a zero row: ker(J^T) is that drive, it gets no force
    np.testing.assert_allclose(out[5][3], 0.0, atol=1e-12)


def _sensor_error(true_offset, true_rotvec, desired):
    sensor = GoughSensorModel(MOM3.metrology)
    feedback = SensorSpaceFeedback(sensor, planar=False)
    p_true = np.array(desired) + true_offset
    r_true = exp_so3(np.array(true_rotvec))
    lengths = sensor.true_lengths(p_true, r_true).tolist()
    p, r = tool_pose_floats(desired, False)
    first = feedback.task_error(p, r, lengths)
    second = feedback.task_error(p, r, lengths)            # J_t at the estimated real pose
    return np.array(first), np.array(second)


@pytest.mark.parametrize("offset_um", [[120.0, -80.0, 130.0], [5.0, 2.0, -4.0]])
def test_sensor_space_error_is_the_tool_offset(offset_um):
    """MoM3 §6.4: J_t e_l is the TCP error x_des - x_real, to second order in the
    offset (exact lengths): |J_t e_l + delta| <= |delta|^2 / 1 m."""
    offset = np.array(offset_um) * 1e-6
    first, second = _sensor_error(offset, [0.0, 0.0, 0.0], [0.05, -0.03, 0.9])
    bound = float(offset @ offset) / 1.0
    assert np.abs(first + offset).max() <= bound
    assert np.abs(second + offset).max() <= bound


@pytest.mark.parametrize("tilt", [2e-4, 2e-3])
def test_sensor_space_sees_the_tool_through_a_parasitic_orientation(tilt):
    """A 3-DOF machine cannot cancel the plate's parasitic tilt, so l_des is never
    reached and e_l stays non-zero with the tool exactly on target. J_t at the
    estimated real pose (MoM3 §6.4) reports a smaller residual tool error than J_t at
    the desired pose (the paper: there "an error of about some microns remains")."""
    at_desired, at_real = _sensor_error(np.zeros(3), [tilt, -0.5 * tilt, 0.0], [0.0, 0.02, 0.85])
    assert np.abs(at_real).max() < 0.7 * np.abs(at_desired).max()
    assert np.abs(at_real).max() < 0.1 * tilt * tilt       # second order: (0.1 m lever) x tilt^2


def test_sensor_space_at_the_desired_pose_keeps_its_first_cycle_error():
    """``at_estimate=False`` (controller sensor_jacobian: desired): J_t stays at the
    desired pose, so every cycle reports the first cycle's residual, which the estimate
    (at_estimate=True) reduces (the test above); the scenario mom3_imperfect measures
    the static error either leaves on the closed loop."""
    sensor = GoughSensorModel(MOM3.metrology)
    desired, tilt = [0.0, 0.02, 0.85], 2e-3
    lengths = sensor.true_lengths(np.array(desired), exp_so3(np.array([tilt, -0.5 * tilt, 0.0]))).tolist()
    p, r = tool_pose_floats(desired, False)
    estimated, at_desired = SensorSpaceFeedback(sensor, planar=False), SensorSpaceFeedback(sensor, False, False)
    first = estimated.task_error(p, r, lengths)
    assert at_desired.task_error(p, r, lengths) == first
    for _ in range(3):
        assert at_desired.task_error(p, r, lengths) == first
    assert np.abs(estimated.task_error(p, r, lengths)).max() < 0.7 * np.abs(first).max()


def test_reference_interpolates_and_holds_the_end():
    t = [0.0, 0.5, 1.0]
    x = [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [2.0, 2.0, 2.0]]
    v = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    ref = Reference(t, x, v, np.zeros((3, 3)))
    xs, vs, _ = ref.sample(0.25)
    assert xs == pytest.approx([0.5, 1.0, 1.5]) and vs == pytest.approx([1.0, 0.0, 0.0])
    assert ref.sample(0.5)[0] == pytest.approx(x[1])
    assert ref.sample(-1.0)[0] == x[0]
    end = ref.sample(7.0)
    assert end[0] == x[2] and end[1] == [0.0, 0.0, 0.0]
    assert ref.duration_s == 1.0 and Reference.hold([1, 2, 3]).duration_s == 0.0


@pytest.mark.parametrize("times, positions, message", [
    ([0.0, 0.0], [[0, 0, 0], [1, 1, 1]], "increase strictly"),
    ([0.0, 1.0], [[0, 0, 0], [1, math.nan, 1]], "positions contain NaN"),
    ([0.0, 1.0], [[0, 0], [1, 1]], r"N x 3 \(or N x 6\) positions, got shapes \(2,\), \(2, 2\)"),
    ([-1.0], [[0, 0, 0]], ">= 0"),
])
def test_reference_refuses_malformed_trajectories(times, positions, message):
    with pytest.raises(ValueError, match=message):
        Reference(times, positions)


def test_every_kernel_outcome_is_described_and_every_limit_trips_with_its_own_cause():
    """The outcome codes (laws.CycleCode, distribution.DistributionCode) each have their
    description, and the supervisor words every limit code with its cause (an unknown
    code falls back to a kinematics trip naming it)."""
    from pkm_common.causes import TripCause
    from pkm_controller.config import ControllerConfig
    from pkm_controller.laws import CYCLE_CODES, CycleCode
    from pkm_controller.supervisor import Supervisor
    from pkm_kinematics.distribution import DISTRIBUTION_CODES, DistributionCode
    assert set(CYCLE_CODES) == set(CycleCode) and all(CYCLE_CODES.values())
    assert set(DISTRIBUTION_CODES) == set(DistributionCode) and all(DISTRIBUTION_CODES.values())
    model = ARCHI.model
    box = np.array([[-1.0, 1.0]] * 4)
    sup = Supervisor(ControllerConfig(), list(model.leg_names), 3, model.task_space, box,
                     np.array([[-1.0, 1.0]] * 3), lambda rows: 1.0, model)
    causes = {code: sup.limit_trip(code, 0, 2.0).cause for code in
              (CycleCode.JOINT_LIMIT, CycleCode.WORKSPACE_LIMIT, CycleCode.SINGULARITY_MARGIN,
               CycleCode.FOLLOWING_ERROR_M, CycleCode.FOLLOWING_ERROR_RAD)}
    assert causes == {CycleCode.JOINT_LIMIT: TripCause.JOINT_LIMIT, CycleCode.WORKSPACE_LIMIT: TripCause.WORKSPACE,
                      CycleCode.SINGULARITY_MARGIN: TripCause.SINGULARITY,
                      CycleCode.FOLLOWING_ERROR_M: TripCause.FOLLOWING_ERROR,
                      CycleCode.FOLLOWING_ERROR_RAD: TripCause.FOLLOWING_ERROR}
    unknown = sup.limit_trip(99, 1, 0.5)
    assert unknown.cause == TripCause.KINEMATICS and "unknown supervisor code 99" in unknown.reason
