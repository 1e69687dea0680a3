"""The hexapods' plant (pkm_sim_hw.strut_plant): a platform on struts in SE(3).
References: the static strut forces of the dynamic model hold the platform still;
scipy's RK45 of the same model in task coordinates (the SE(3) integrator against an
independent one); the strut readings are the quantised inverse kinematics; faults, end stops and loads as the rail plant's."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pkm_kinematics import load_machine
from pkm_kinematics.rotations import rate_matrix, rotation_from_rpy
from pkm_sim_hw.plant import PlantParameters
from pkm_sim_hw.strut_plant import StrutPlant

HEXAPOD = load_machine("genhexkins")
HEXAPOD8 = load_machine("hexapod8")


def static_forces(plant, x):
    """Strut forces holding the platform at x: J_m^T f = H(x, 0) (least norm)."""
    wrench = plant.dynamics.static_forces(x)
    return np.linalg.lstsq(plant.machine.jacobian(x).T, wrench, rcond=None)[0]


@pytest.mark.parametrize("config", [HEXAPOD, HEXAPOD8], ids=["genhexkins", "hexapod8"])
def test_the_static_forces_hold_the_platform_and_the_readings_are_its_strut_lengths(config):
    plant = StrutPlant(config, PlantParameters(encoder_resolution_m=1e-6))
    x0 = np.array(plant.x)
    forces = static_forces(plant, x0)
    for _ in range(200):
        out = plant.step(forces.tolist())
    np.testing.assert_allclose(out.tool_pose, x0, atol=1e-9)
    q = config.model.inverse_kinematics(np.array(out.tool_pose))
    np.testing.assert_allclose(out.encoder_positions, np.round(q / 1e-6) * 1e-6, atol=1e-15)
    assert np.abs(out.encoder_velocities).max() < 1e-9
    # the redundant hexapod's least-norm forces fight nothing: no internal force
    assert out.internal_force_norm < 1e-6 * np.abs(forces).max()
    # without them the platform falls
    plant = StrutPlant(config)
    for _ in range(50):
        out = plant.step([0.0] * config.model.n_legs)
    assert out.tool_pose[2] < x0[2] - 1e-4


def test_the_plant_integrates_its_dynamics_on_se3_to_first_order():
    """Constant strut forces (the static ones plus a push) for 0.2 s: the plant's pose
    against scipy's RK45 of the same Newton-Euler model written in the task
    coordinates (x' = (v, E^-1 w), t' = forward dynamics) to 1e-10; the semi-implicit
    Euler step on SE(3) is first order: ten substeps divide the error by ~10."""
    model = HEXAPOD.model
    probe = StrutPlant(HEXAPOD)
    x0 = np.array(probe.x)
    forces = static_forces(probe, x0) + [40.0, -25.0, 10.0, 30.0, -35.0, 5.0]

    def rhs(_t, y):
        x, twist = y[:6], y[6:]
        rates = np.linalg.solve(rate_matrix(*x[3:]), twist[3:])
        return np.concatenate((twist[:3], rates, probe.dynamics.forward_dynamics(x, twist, forces)))

    exact = solve_ivp(rhs, (0.0, 0.2), np.concatenate((x0, np.zeros(6))), rtol=1e-11, atol=1e-12).y[:6, -1]
    error = {}
    for substeps in (1, 10):
        plant = StrutPlant(HEXAPOD, PlantParameters(encoder_resolution_m=0.0, substeps=substeps))
        for _ in range(200):
            out = plant.step(forces.tolist())
        error[substeps] = float(np.abs(np.array(out.tool_pose) - exact).max())
    moved = float(np.abs(exact - x0).max())
    assert moved > 1e-3 and error[1] < 0.05 * moved and 7.0 < error[1] / error[10] < 13.0, (error, moved)
    np.testing.assert_allclose(np.array(out.tool_rotation).reshape(3, 3), rotation_from_rpy(*out.tool_pose[3:]),
                               atol=1e-12)
    np.testing.assert_allclose(out.encoder_positions, model.inverse_kinematics(np.array(out.tool_pose)), atol=1e-12)


def test_saturation_faults_end_stops_and_loads():
    plant = StrutPlant(HEXAPOD, PlantParameters(force_limit_n=300.0, faults=("2:no_force", "4:encoder_freeze:0.005")))
    x0 = np.array(plant.x)
    forces = static_forces(plant, x0)
    out = plant.step([1000.0] + forces[1:].tolist())
    assert out.saturated[0] and out.applied_forces[0] == 300.0 and out.applied_forces[2] == 0.0
    frozen = None
    for _ in range(20):
        out = plant.step(forces.tolist())
        frozen = frozen if plant.t < 0.006 else (frozen or out.encoder_positions[4])
    assert out.encoder_positions[4] == frozen and out.encoder_velocities[4] == 0.0
    with pytest.raises(ValueError, match=r"load: mz must be in \[-500, 500\] N m \(max_load_nm\), got 600"):
        plant.set_load([0.0, 0.0, 0.0, 0.0, 0.0, 600.0])
    # pushed up at full force, the struts reach their upper end stop: the machine brakes
    plant = StrutPlant(HEXAPOD, PlantParameters(force_limit_n=5000.0))
    for _ in range(3000):
        out = plant.step([5000.0] * 6)
        if out.stopped:
            break
    assert out.stopped and "end stop" in plant.stop_reason and out.applied_forces == [0.0] * 6
    held = plant.step([5000.0] * 6)
    assert held.tool_pose == out.tool_pose
    with pytest.raises(ValueError, match="rail_offset_errors_m: not simulated on a strut machine yet"):
        StrutPlant(HEXAPOD, PlantParameters(rail_offset_errors_m=(1e-6,) + (0.0,) * 5))


def test_a_strut_error_makes_its_reading_short_of_the_true_length():
    """link_length_errors on a strut machine: strut k is (1 + e_k) times its reading."""
    params = PlantParameters(link_length_errors=(0.01, 0, 0, -0.02, 0, 0, 0, 0), encoder_resolution_m=0.0)
    plant = StrutPlant(HEXAPOD8, params)
    out = plant.step(static_forces(plant, plant.x))
    true = HEXAPOD8.model.strut_lengths(plant.p, plant.rotation)
    np.testing.assert_allclose(out.encoder_positions, true / [1.01, 1, 1, 0.98, 1, 1, 1, 1], rtol=1e-15)


def test_a_scheduled_load_deflects_the_tool_by_its_compliance_unseen_by_the_struts():
    """A load from t_s on (counted in steps), and C f_load on the tool only."""
    c = (1e-6, 2e-6, 3e-6, 1e-5, 2e-5, 3e-5)
    params = PlantParameters(compliance=c, encoder_resolution_m=0.0)
    plant = StrutPlant(HEXAPOD8, params)
    load = [100.0, -50.0, 20.0, 5.0, -4.0, 3.0]
    plant.schedule_load([(0.003, load)])
    hold = static_forces(plant, plant.x)
    outs = [plant.step(hold) for _ in range(4)]
    assert outs[2].tool_pose == outs[2].rigid_pose                      # steps 0-2 (t < 3 ms): no load yet
    np.testing.assert_allclose(np.subtract(outs[3].tool_pose, outs[3].rigid_pose), np.multiply(c, load),
                               rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.reshape(outs[3].tool_rotation, (3, 3)), rotation_from_rpy(*outs[3].tool_pose[3:]))
    rigid = StrutPlant(HEXAPOD8, PlantParameters(encoder_resolution_m=0.0))   # the same motion, no compliance
    for _ in range(3):
        rigid.step(hold)
    rigid.set_load(load)
    np.testing.assert_allclose(rigid.step(hold).encoder_positions, outs[3].encoder_positions, atol=1e-15)
    with pytest.raises(ValueError, match=r"load_schedule: mx must be in \[-500, 500\] N m"):
        plant.schedule_load([(0.0, [0, 0, 0, 600.0, 0, 0])])
    with pytest.raises(ValueError, match="compliance: must be 6 values on a 6-DOF machine"):
        StrutPlant(HEXAPOD8, PlantParameters(compliance=(1e-6, 0.0, 0.0)))


def test_a_frame_load_carries_the_tool_with_the_whole_strut_chain_unseen_by_the_encoders():
    """frame_load on a strut machine (MoM3 §7.1.2 on 6 DOF): the frame carrying the
    base joints deflects by C_frame f_frame, the platform and tool with it; the struts
    keep their lengths (the same readings as a twin without it, bit for bit), the
    platform load and the frame load add on the tool."""
    cf = (7e-8, 7e-8, 5e-8, 1e-7, 1e-7, 2e-7)
    c = (1e-6, 0.0, 0.0, 0.0, 0.0, 0.0)
    params = PlantParameters(frame_compliance=cf, compliance=c, encoder_resolution_m=0.0)
    loaded, plain = StrutPlant(HEXAPOD8, params), StrutPlant(HEXAPOD8, PlantParameters(encoder_resolution_m=0.0))
    frame = [0.0, 850.0, -300.0, 20.0, 0.0, -10.0]
    loaded.schedule_frame_load([(0.002, frame)])
    loaded.set_load([10.0, 0, 0, 0, 0, 0])
    plain.set_load([10.0, 0, 0, 0, 0, 0])              # the same platform load: only the frame's differs
    hold = static_forces(plain, plain.x)
    for k in range(4):
        out, ref = loaded.step(hold), plain.step(hold)
        assert out.encoder_positions == ref.encoder_positions and out.rigid_pose == ref.rigid_pose
        expected = np.multiply(c, [10.0, 0, 0, 0, 0, 0]) + (np.multiply(cf, frame) if k >= 2 else 0.0)
        np.testing.assert_allclose(np.subtract(out.tool_pose, out.rigid_pose), expected, rtol=1e-9, atol=1e-15)
    assert out.tool_pose[1] - out.rigid_pose[1] == pytest.approx(59.5e-6, rel=1e-9)
    np.testing.assert_allclose(np.reshape(out.tool_rotation, (3, 3)), rotation_from_rpy(*out.tool_pose[3:]))
    with pytest.raises(ValueError, match="frame_compliance: must be 6 values on a 6-DOF machine"):
        StrutPlant(HEXAPOD8, PlantParameters(frame_compliance=(1e-6, 0.0, 0.0)))
    with pytest.raises(ValueError, match=r"frame_load_schedule: fy must be in \[-5000, 5000\] N"):
        loaded.schedule_frame_load([(0.0, [0, 6000.0, 0, 0, 0, 0])])


@pytest.mark.parametrize("config", [HEXAPOD, HEXAPOD8], ids=["genhexkins", "hexapod8"])
@pytest.mark.parametrize("substeps", [1, 3])
def test_the_compiled_step_is_the_python_step_to_the_bit(config, substeps):
    """StrutPlant.step in two compiled calls (strut_step.py) against the interpreted
    step, its reference: the same state and outputs at every step under random forces
    about the holding forces, with every encoder term (noise from the same draws, screw
    errors, offsets, a strut's length error), saturation and scheduled loads; then the
    same stop at an end stop."""
    n = config.model.n_legs
    params = dict(substeps=substeps, link_length_errors=(0.01,) + (0.0,) * (n - 1), encoder_noise_m=2e-7, seed=11,
                  screw_errors_m=tuple(2e-6 * (i + 1) for i in range(n)), screw_error_period_m=0.05,
                  encoder_offsets_m=tuple(0.013 * (i - 1) for i in range(n)), encoder_resolution_m=1e-8)
    probe = StrutPlant(config, PlantParameters(**params))
    hold = static_forces(probe, np.array(probe.x))
    params["force_limit_n"] = float(np.abs(hold).max() + 60.0)
    compiled, python = StrutPlant(config, PlantParameters(**params)), StrutPlant(config, PlantParameters(**params))
    python.compiled_step = False
    assert compiled._compiled is not None
    for plant in (compiled, python):
        plant.schedule_load([(0.05, [30.0, -20.0, 10.0, 1.0, -2.0, 0.5]), (0.2, [0.0] * 6)])
    rng = np.random.default_rng(5)
    saturated = 0
    for k in range(300):
        forces = (hold + rng.normal(0.0, 60.0, n)).tolist()
        a, b = compiled.step(forces), python.step(forces)
        assert (a, compiled.x, compiled.twist.tolist(), compiled.load.tolist()) == \
            (b, python.x, python.twist.tolist(), python.load.tolist()), k
        saturated += any(a.saturated)
    assert saturated > 20 and not a.stopped and (a.internal_force_norm > 0.0) == (n > 6), (saturated, a)
    with pytest.raises(ValueError, match="drive forces"):
        compiled.step([math.nan] * n)
    # pushed up at full force: the same end stop, braked
    compiled = StrutPlant(config, PlantParameters(substeps=substeps, force_limit_n=5000.0))
    python = StrutPlant(config, PlantParameters(substeps=substeps, force_limit_n=5000.0))
    python.compiled_step = False
    for k in range(3000):
        a, b = compiled.step([5000.0] * n), python.step([5000.0] * n)
        assert (a, compiled.x, compiled.stop_reason) == (b, python.x, python.stop_reason), k
        if compiled.stopped:
            break
    assert compiled.stopped and "end stop" in compiled.stop_reason, compiled.stop_reason
