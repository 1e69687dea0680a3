"""The controller on 6 task DOF (issue 23): the hexapods (LinuxCNC's genhexkins, the
redundant hexapod8) against the SE(3) plant, in closed loop without ROS, and the
spatial pieces the cycle is built of, each against an independent reference
(scipy's rotations, finite differences, the forward dynamics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pkm_common.causes import TripCause
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.laws import apparent_drive_mass, spatial_pose_error
from pkm_controller.reference import Reference
from pkm_kinematics import load_machine
from pkm_kinematics.rigid_body import StrutDynamics
from pkm_kinematics.rotations import rotation_from_rpy
from pkm_kinematics.task_space import SPATIAL, task_twists
from pkm_sim_hw.plant import PlantParameters
from pkm_sim_hw.strut_plant import StrutPlant

GENHEXKINS = load_machine("genhexkins")
HEXAPOD8 = load_machine("hexapod8")


def _move(home, delta, duration_s=0.6, points=121) -> Reference:
    """home -> home + delta on a cosine profile, with its exact rates."""
    t = np.linspace(0.0, duration_s, points)
    w = math.pi / duration_s
    s, ds, dds = 0.5 - 0.5 * np.cos(w * t), 0.5 * w * np.sin(w * t), 0.5 * w * w * np.cos(w * t)
    d = np.asarray(delta, dtype=float)
    return Reference(t, home + np.outer(s, d), np.outer(ds, d), np.outer(dds, d))


def test_the_spatial_pose_error_is_the_rotation_vector_of_rd_rt():
    rng = np.random.default_rng(7)
    for _ in range(20):
        x_d, x = rng.uniform(-0.5, 0.5, 6), rng.uniform(-0.5, 0.5, 6)
        e = spatial_pose_error(x_d.tolist(), x.tolist())
        r_d = Rotation.from_euler("ZYX", x_d[[5, 4, 3]])       # R = Rz(c) Ry(b) Rx(a)
        r = Rotation.from_euler("ZYX", x[[5, 4, 3]])
        np.testing.assert_allclose(e[:3], x_d[:3] - x[:3], atol=1e-15)
        np.testing.assert_allclose(e[3:], (r_d * r.inv()).as_rotvec(), atol=1e-12)


def test_the_reference_twist_is_the_rotations_angular_velocity():
    """task_twists against finite differences of R(t) = R(angles(t)): w = vee(R' R^T)."""
    x0, v, a = np.array([0.1, 0.2, 0.5, 0.2, -0.3, 0.4]), np.array([0.1, 0, 0, 0.5, -0.7, 0.3]), \
        np.array([0, 0, 0, 1.0, 2.0, -1.5])
    h = 1e-6

    def rotation(t):
        return rotation_from_rpy(*(x0[3:] + v[3:] * t + 0.5 * a[3:] * t * t))

    def omega(t):
        d = (rotation(t + h) - rotation(t - h)) / (2 * h) @ rotation(t).T
        return np.array([d[2, 1], d[0, 2], d[1, 0]])
    twist, twist_rate = task_twists(SPATIAL, x0.tolist(), v.tolist(), a.tolist())
    np.testing.assert_allclose(twist[3:], omega(0.0), atol=1e-8)
    np.testing.assert_allclose(twist_rate[3:], (omega(1e-4) - omega(-1e-4)) / 2e-4, atol=1e-5)
    np.testing.assert_allclose(twist[:3], v[:3]) and np.testing.assert_allclose(twist_rate[:3], a[:3])


def test_strut_velocity_terms_against_finite_differences():
    """q' = J_m t and q'' = J_m t' + J_m' t along a screw motion of the platform."""
    model = GENHEXKINS.model
    x0 = model.home + np.array([0.01, -0.02, 0.01, 0.05, -0.03, 0.08])
    twist = np.array([0.02, -0.01, 0.03, 0.2, -0.1, 0.3])
    p0, r0 = model.pose(x0)
    h = 1e-5

    def lengths(t):      # constant twist in the base frame: p' = v, R' = [w]x R
        return model.strut_lengths(p0 + twist[:3] * t, Rotation.from_rotvec(twist[3:] * t).as_matrix() @ r0)
    q, jac, qdot, bias = model.velocity_terms(x0, twist)
    np.testing.assert_allclose(q, lengths(0.0), atol=1e-15)
    np.testing.assert_allclose(qdot, (lengths(h) - lengths(-h)) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(bias, (lengths(h) - 2 * lengths(0.0) + lengths(-h)) / (h * h), atol=1e-4)


def test_the_measured_twist_explains_the_drive_velocities():
    dyn = StrutDynamics(HEXAPOD8.model, HEXAPOD8.dynamics)
    x = HEXAPOD8.model.home + np.array([0.02, 0.0, -0.03, 0.05, 0.02, -0.1])
    twist = np.array([0.1, -0.2, 0.05, 0.3, 0.1, -0.4])
    qdot = HEXAPOD8.model.jacobian(x) @ twist
    a, h, jac, measured = dyn.measured_state(x, qdot)
    np.testing.assert_allclose(measured, twist, atol=1e-12)
    a_ref, h_ref, _ = dyn.terms(x, twist)
    np.testing.assert_allclose(a, a_ref, atol=1e-12) and np.testing.assert_allclose(h, h_ref, atol=1e-9)


def test_the_apparent_drive_mass_is_what_a_strut_pushing_alone_accelerates():
    dyn = StrutDynamics(HEXAPOD8.model, HEXAPOD8.dynamics)
    x = HEXAPOD8.model.home
    a, _, jac, _ = dyn.measured_state(x, np.zeros(8))
    masses = apparent_drive_mass(jac, a)
    for i in range(8):
        push = np.zeros(8)
        push[i] = 10.0
        acc = dyn.forward_dynamics(x, np.zeros(6), push) - dyn.forward_dynamics(x, np.zeros(6), np.zeros(8))
        assert masses[i] == pytest.approx(10.0 / (jac[i] @ acc), rel=1e-9)


@pytest.mark.parametrize("strategy", ["computed_torque", "cartesian_pid", "joint_pid", "decentralized_projected"])
def test_every_encoder_strategy_tracks_a_six_dof_move_of_genhexkins(strategy):
    """x, y, z and all three angles at once, through the SE(3) plant."""
    home = GENHEXKINS.model.home
    ref = _move(home, [0.01, -0.01, 0.005, 0.02, -0.02, 0.03])
    core, log = run(GENHEXKINS, ControllerConfig(strategy=strategy), StrutPlant(GENHEXKINS), 900, reference=ref)
    assert core.mode == "holding" and not core.stopped
    tool, reference = np.array(log.tool), np.array(log.reference)
    error = np.linalg.norm(tool[:, :3] - reference[:, :3], axis=1)
    bound = 5e-6 if strategy == "computed_torque" else 1e-3        # the model-based law tracks tightest
    assert error.max() < bound
    assert error[-1] < 2e-6                                       # at rest at the end: the integral's work
    np.testing.assert_allclose(tool[-1, 3:], home[3:] + [0.02, -0.02, 0.03], atol=1e-5)


def test_joint_pids_fight_over_an_inconsistent_strut_and_the_projection_does_not():
    """Sliding Star eq. 6-8 on 8 struts: 1 % error on s1 (T_i = 0.1 s: hexapod8's joint
    PIDs need more than 0.067 s, test_gain_stability.py)."""
    params = PlantParameters(link_length_errors=(0.01, 0, 0, 0, 0, 0, 0, 0))
    pid, pid_log = run(HEXAPOD8, ControllerConfig(strategy="joint_pid", integral_time_s=0.1),
                       StrutPlant(HEXAPOD8, params), 1000)
    assert pid.stopped and pid.stop_cause == TripCause.SATURATION
    assert max(pid_log.internal_force_norm_n) > 1000.0
    proj, proj_log = run(HEXAPOD8, ControllerConfig(strategy="decentralized_projected", integral_time_s=0.1),
                         StrutPlant(HEXAPOD8, params), 1000)
    assert not proj.stopped and max(proj_log.internal_force_norm_n) < 10.0


def test_a_frozen_strut_encoder_is_named():
    home = GENHEXKINS.model.home
    plant = StrutPlant(GENHEXKINS, PlantParameters(faults=("3:encoder_freeze:0.2",)))
    core, _ = run(GENHEXKINS, ControllerConfig(strategy="computed_torque"), plant, 600,
                  reference=_move(home, [0.02, 0.0, 0.0, 0.0, 0.0, 0.0]))
    assert core.stopped and core.stop_cause == TripCause.ENCODER_FAULT and "drive j3" in core.stop_reason


def test_what_a_spatial_machine_cannot_take_is_refused_by_name():
    core = ControllerCore(GENHEXKINS, ControllerConfig())
    core.update(0, GENHEXKINS.model.inverse_kinematics(GENHEXKINS.model.home).tolist(), [0.0] * 6)
    with pytest.raises(ValueError, match=r"3 task coordinates, this machine has 6 \(x, y, z, a, b, c\)"):
        core.set_trajectory(Reference.hold([0.0, 0.0, 0.5]))
    with pytest.raises(ValueError, match="forward_kinematics: must be newton on a 6-DOF machine"):
        ControllerCore(GENHEXKINS, ControllerConfig(forward_kinematics="integrated"))
    with pytest.raises(ValueError, match=r"prestress_n: must be 0, or finite on a machine with one redundant drive "
                                         r"\(4 drives\) or with a prestress_direction"):
        ControllerCore(HEXAPOD8, ControllerConfig(prestress_n=100.0))
    with pytest.raises(ValueError, match=r"prestress_n: must be 0 on a machine without redundant drives \(6 drives"):
        ControllerCore(GENHEXKINS, ControllerConfig(prestress_n=100.0, prestress_direction=(1.0,) * 6))
    with pytest.raises(ValueError, match=r"prestress_direction: must be empty, or 8 finite drive forces"):
        ControllerCore(HEXAPOD8, ControllerConfig(prestress_n=100.0, prestress_direction=(1.0,) * 6))
    with pytest.raises(ValueError, match=r"prestress_direction: prestress: direction has no internal part .* at home"):
        ControllerCore(HEXAPOD8, ControllerConfig(prestress_n=100.0, prestress_direction=(1.0, -1.0) * 4))


@pytest.mark.parametrize("distribution", ["pseudo_inverse", "inf_norm"])
def test_a_redundant_hexapod_is_prestressed_along_the_chosen_internal_force(distribution):
    """hexapod8's internal forces span 2 dimensions: prestress_direction picks the one
    nearest a pattern of the eight struts; the commands carry prestress_n of it (on
    the pseudo-inverse) and the platform still holds."""
    from pkm_kinematics.distribution import internal_force, prestress_direction
    pattern = (1.0, 1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0)     # pairs s1-s2, s5-s6 against s3-s4, s7-s8
    config = ControllerConfig(strategy="computed_torque", distribution=distribution, prestress_n=300.0,
                              prestress_direction=pattern)
    core, log = run(HEXAPOD8, config, StrutPlant(HEXAPOD8), 300)
    assert not core.stopped
    tool = np.array(log.tool[-1])
    assert np.linalg.norm(tool[:3] - HEXAPOD8.model.home[:3]) < 2e-6
    jac = HEXAPOD8.model.jacobian(HEXAPOD8.model.home)
    internal = internal_force(jac, log.forces[-1])
    if distribution == "pseudo_inverse":              # f = J (J^T J)^-1 F + 300 n: n exactly
        np.testing.assert_allclose(internal, 300.0 * prestress_direction(jac, pattern), atol=0.5)
    else:                                             # the least peak moved by 300 n
        assert np.linalg.norm(internal) > 250.0


def test_the_sensor_space_error_of_a_spatial_tool_is_its_pose_offset():
    """MoM3 §6.4 on 6 DOF: readings of the Gough at a tool offset by (dp, dw) from the
    desired pose give the error (dp, dw) (first order: J_h e_l)."""
    from pkm_controller.laws import tool_pose_floats
    from pkm_controller.sensor_space import SensorSpaceFeedback
    from pkm_gough_sensor.metrology import GoughSensorModel
    sensor = GoughSensorModel(HEXAPOD8.metrology)
    feedback = SensorSpaceFeedback(sensor, planar=False, spatial=True)
    x_d = HEXAPOD8.model.home + np.array([0.02, -0.01, 0.03, 0.05, -0.04, 0.08])
    p_d, r_d = tool_pose_floats(x_d.tolist(), False)
    offset = np.array([3e-6, -2e-6, 4e-6, 5e-6, -3e-6, 2e-6])          # x_des - x_real
    real_r = Rotation.from_rotvec(-offset[3:]).as_matrix() @ np.array(r_d).reshape(3, 3)
    lengths = sensor.true_lengths(np.array(p_d) - offset[:3], real_r)
    np.testing.assert_allclose(feedback.task_error(p_d, r_d, lengths.tolist()), offset, atol=1e-10)


@pytest.mark.parametrize("strategy", ["sensor_space", "measured_space"])
def test_the_gough_metrology_removes_strut_errors_the_encoders_cannot_see(strategy):
    """hexapod8 with pitch errors on three strut screws: encoder control holds the tool
    ~1 mm off; control on the Gough struts or its pose holds it within microns."""
    from pkm_gough_sensor.metrology import GoughSensorModel
    params = PlantParameters(link_length_errors=(0.002, 0, -0.001, 0, 0.0015, 0, 0, 0))
    home = HEXAPOD8.model.home
    ref = _move(home, [0.03, -0.02, 0.02, 0.05, -0.04, 0.08])
    ends = {}
    for name in ("computed_torque", strategy):
        core, log = run(HEXAPOD8, ControllerConfig(strategy=name), StrutPlant(HEXAPOD8, params), 1000,
                        reference=ref, sensor=GoughSensorModel(HEXAPOD8.metrology))
        assert not core.stopped, core.stop_reason
        tool, reference = np.array(log.tool[-1]), np.array(log.reference[-1])
        ends[name] = (np.linalg.norm(tool[:3] - reference[:3]),
                      (Rotation.from_euler("ZYX", reference[[5, 4, 3]])
                       * Rotation.from_euler("ZYX", tool[[5, 4, 3]]).inv()).magnitude())
    assert ends["computed_torque"][0] > 500e-6
    assert ends[strategy][0] < 3e-6 and ends[strategy][1] < 20e-6


# ------------------------------------------------------ the spatial kernels alone
def _spatial_inputs(seed=4):
    """A hexapod's J_m at a pose near home, with boxes that hold it, and random law inputs."""
    from pkm_kinematics import load_machine
    model = load_machine("genhexkins").model
    rng = np.random.default_rng(seed)
    x = np.asarray(model.home, dtype=float) + rng.uniform(-0.002, 0.002, 6)
    q = model.inverse_kinematics(x)
    rows = np.asarray(model.jacobian(x), dtype=float)
    joint_box = np.column_stack([q - 0.1, q + 0.1])
    workspace_box = np.column_stack([x - 0.1, x + 0.1])
    return model, rng, x, q, rows, joint_box, workspace_box


def test_spatial_limits_kernel_names_each_limit_in_order():
    """Against the definitions: the first drive out of its box, the first axis out of
    the workspace, the weighted condition number, |e_p| and |e_w| (a rotation vector's
    angle), in that order."""
    from pkm_controller.laws import CycleCode, kernel_settings, spatial_limits_kernel
    model, rng, x, q, rows, joint_box, workspace_box = _spatial_inputs()
    length = model.characteristic_length_m
    cond = np.linalg.cond(np.hstack([rows[:, :3], rows[:, 3:] / length]))   # rotation columns weighted
    error = (0.001, -0.002, 0.0005, 0.01, 0.0, -0.02)

    def limits(q_, measured, max_condition=1e6, err=error, fe_m=0.01, fe_rad=0.05):
        return spatial_limits_kernel(q_, rows, np.asarray(measured, dtype=float), np.asarray(err),
                                     (joint_box, workspace_box),
                                     kernel_settings(max_condition, fe_m, fe_rad, 1e9, length))
    code, index, value = limits(q, x)
    assert code == CycleCode.OK and value == pytest.approx(np.linalg.norm(error[:3]), rel=1e-12)
    bad_q = q.copy(); bad_q[4] = joint_box[4, 1] + 1e-6
    assert limits(bad_q, x)[:2] == (CycleCode.JOINT_LIMIT, 4)
    bad_x = x.copy(); bad_x[5] = workspace_box[5, 0] - 1e-6
    assert limits(q, bad_x)[:2] == (CycleCode.WORKSPACE_LIMIT, 5)
    code, _, value = limits(q, x, max_condition=0.5 * cond)
    assert code == CycleCode.SINGULARITY_MARGIN and value == pytest.approx(cond, rel=1e-9)
    assert limits(q, x, fe_m=1e-4)[0] == CycleCode.FOLLOWING_ERROR_M
    code, index, value = limits(q, x, fe_rad=1e-3)
    assert (code, index) == (CycleCode.FOLLOWING_ERROR_RAD, 3) and value == pytest.approx(np.linalg.norm(error[3:]))


def test_spatial_command_kernel_is_computed_torque_and_the_pseudo_inverse():
    """F = A (a_d + Kd (v_d - v) + Kp e + I) + H and f = J (J^T J)^-1 F, against numpy;
    the integral grows by Ki e dt; the wrench comes back alone without distribution."""
    from pkm_controller.laws import (DIST_PSEUDO_INVERSE, LAW_COMPUTED_TORQUE, NUMPY_DISTRIBUTION, CycleCode,
                                     kernel_settings, spatial_command_kernel)
    model, rng, x, q, rows, joint_box, workspace_box = _spatial_inputs(9)
    kp, kd, ki = 400.0, 40.0, 2000.0
    gains = np.array([[kp] * 6, [kd] * 6, [ki] * 6, [0.0] * 6])
    error = rng.uniform(-1e-4, 1e-4, 6)
    integral = rng.uniform(-0.1, 0.1, 6)
    a_model = np.diag(rng.uniform(5.0, 20.0, 6)) + 0.1
    h_model = rng.uniform(-50.0, 50.0, 6)
    v_d, v, a_d = rng.uniform(-0.01, 0.01, 6), rng.uniform(-0.01, 0.01, 6), rng.uniform(-0.1, 0.1, 6)
    dt = 0.001

    def command(distribute):
        task = np.array([x, error, v_d, v, a_d])                       # laws.TASK_* rows
        modes = (0, LAW_COMPUTED_TORQUE, DIST_PSEUDO_INVERSE if distribute else NUMPY_DISTRIBUTION)
        return spatial_command_kernel(q, rows, task, (a_model, h_model), integral, True, dt,
                                      (joint_box, workspace_box), gains,
                                      kernel_settings(1e6, 0.01, 0.05, 1e9, model.characteristic_length_m), modes)
    code, _, _, i_new, wrench, forces, saturated, peak = command(True)
    i_ref = integral + ki * error * dt
    wrench_ref = a_model @ (a_d + kd * (v_d - v) + kp * error + i_ref) + h_model
    forces_ref = rows @ np.linalg.solve(rows.T @ rows, wrench_ref)
    assert code == CycleCode.OK and saturated == 0
    np.testing.assert_allclose(i_new, i_ref, rtol=1e-12)
    np.testing.assert_allclose(wrench, wrench_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(forces, forces_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(rows.T @ forces, wrench_ref, rtol=1e-9, atol=1e-9)
    assert peak == pytest.approx(np.abs(forces_ref).max(), rel=1e-9)
    code, _, _, _, wrench_only, forces_none, _, _ = command(False)
    assert code == CycleCode.OK and forces_none.shape == (0,)
    np.testing.assert_allclose(wrench_only, wrench_ref, rtol=1e-12, atol=1e-12)
