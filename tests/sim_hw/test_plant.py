"""The simulated machine: integration accuracy, physics identities, drives, encoders,
compliance, internal force, faults and input validation."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pkm_kinematics import load_machine
from pkm_kinematics.distribution import min_two_norm
from pkm_sim_hw.plant import Fault, Plant, PlantParameters, command_efforts

ARCHI = load_machine("archi")
MOM3 = load_machine("mom3")
POSE = [1.0, -0.4, 0.9]


def holding_forces(plant, load=(0.0, 0.0, 0.0), jacobian_of=None):
    """Pseudo-inverse forces that hold the platform still (static wrench minus load)."""
    machine = jacobian_of or plant.machine
    wrench = plant.dynamics.static_forces(plant.x, load)
    return min_two_norm(machine.jacobian(plant.x), wrench)


def test_integration_matches_solve_ivp():
    """0.1 s of free motion under constant forces: RK4 agrees with scipy's solve_ivp to
    1e-9 m; semi-implicit Euler is first order (halving dt halves its error)."""
    forces = [50.0, -80.0, 120.0, -40.0]

    def run(integrator, dt, substeps=1):
        plant = Plant(ARCHI, PlantParameters(dt_s=dt, substeps=substeps, integrator=integrator,
                                             encoder_resolution_m=0.0), initial_pose=POSE)
        plant.v = [0.05, -0.02, 0.3]
        for _ in range(round(0.1 / dt)):
            plant.step(forces)
        return np.array(plant.x)

    ref_model = Plant(ARCHI, PlantParameters(), initial_pose=POSE).dynamics
    sol = solve_ivp(lambda _t, s: [*s[3:], *ref_model.forward_dynamics(list(s[:3]), list(s[3:]), forces)],
                    (0.0, 0.1), [*POSE, 0.05, -0.02, 0.3], rtol=1e-12, atol=1e-13)
    reference = sol.y[:3, -1]
    assert np.abs(run("rk4", 1e-3) - reference).max() < 1e-9
    e1 = np.abs(run("semi_implicit", 1e-3) - reference).max()
    e2 = np.abs(run("semi_implicit", 5e-4) - reference).max()
    assert e1 < 1e-3 and 1.7 < e1 / e2 < 2.3
    assert np.abs(run("semi_implicit", 1e-3, substeps=10) - reference).max() < e1 / 5


def test_energy_conserved_without_friction_and_forces():
    cfg = load_machine("mom3")
    cfg = dataclasses.replace(cfg, dynamics=dataclasses.replace(cfg.dynamics, friction_ns_per_m=(0.0, 0.0, 0.0)))
    plant = Plant(cfg, PlantParameters(integrator="rk4", encoder_resolution_m=0.0))
    plant.v = [0.1, -0.05, 0.2]
    e0 = plant.dynamics.energy(plant.x, plant.v)
    for _ in range(100):
        assert not plant.step([0.0, 0.0, 0.0]).stopped
    assert abs(plant.dynamics.energy(plant.x, plant.v) - e0) < 1e-8 * abs(e0)
    assert abs(plant.x[2] - MOM3.model.home[2]) > 1e-3      # it fell


def test_static_equilibrium_and_saturation():
    plant = Plant(ARCHI, PlantParameters(encoder_resolution_m=0.0), initial_pose=POSE)
    forces = holding_forces(plant)
    for _ in range(200):
        out = plant.step(forces)
    np.testing.assert_allclose(plant.x, POSE, atol=1e-12)
    assert not any(out.saturated)
    out = plant.step([1e5, -1e5, 10.0, 0.0])
    assert out.saturated == [True, True, False, False]
    assert out.applied_forces[:2] == [2000.0, -2000.0]


def test_encoders_are_quantised():
    plant = Plant(ARCHI, PlantParameters(encoder_resolution_m=1e-6), initial_pose=POSE)
    plant.v = [0.01, 0.02, 0.1]
    for _ in range(20):
        out = plant.step([0.0] * 4)
    true_q = plant.machine.inverse_kinematics(plant.x, check_limits=False)
    steps = np.array(out.encoder_positions) / 1e-6
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    assert np.abs(np.array(out.encoder_positions) - true_q).max() <= 0.5e-6 + 1e-15
    # the velocity estimate is the backward difference of the readings
    previous = out.encoder_positions
    out = plant.step([0.0] * 4)
    np.testing.assert_allclose(out.encoder_velocities, (np.array(out.encoder_positions) - previous) / 1e-3)


def test_deflection_is_compliance_times_load_and_invisible_to_encoders():
    """MoM3 §7.1: ~73 um under 110 N, seen by the metrology, not by the Delta."""
    c = 0.7e-6
    params = PlantParameters(compliance=(c, c, c), encoder_resolution_m=0.0)
    plain, loaded = Plant(MOM3, params), Plant(MOM3, params)
    load = (0.0, 110.0, 0.0)
    loaded.set_load(load)
    for _ in range(50):
        out0 = plain.step(holding_forces(plain))
        out1 = loaded.step(holding_forces(loaded, load))
    np.testing.assert_allclose(np.array(out1.tool_pose) - np.array(out1.rigid_pose), c * np.array(load), atol=1e-15)
    assert out1.tool_pose[1] - out0.tool_pose[1] == pytest.approx(77e-6, rel=1e-9)
    np.testing.assert_allclose(out1.encoder_positions, out0.encoder_positions, atol=1e-12)


def test_a_frame_load_moves_the_tool_with_the_actuation_chain_unseen_by_the_encoders():
    """MoM3 §7.1.2, Table 3: 850 N on the Delta's frame moves the whole actuation chain
    by C_frame f (here 70 nm/N: 59.5 um), the tool with it; the platform's dynamics and
    the encoders do not change (the drives hold the same positions on a moved frame).
    Scheduled in simulated time, from the first step at or after t_s."""
    cf = 7e-8
    params = PlantParameters(frame_compliance=(cf, cf, cf), encoder_resolution_m=0.0)
    plain, loaded = Plant(MOM3, params), Plant(MOM3, params)
    loaded.schedule_frame_load([(0.01, (0.0, 850.0, 0.0))])
    for k in range(50):
        out0 = plain.step(holding_forces(plain))
        out1 = loaded.step(holding_forces(loaded))
        if k == 5:                   # before 10 ms: no frame load yet
            assert out1.tool_pose == out1.rigid_pose
    assert out1.tool_pose[1] - out1.rigid_pose[1] == pytest.approx(59.5e-6, rel=1e-9)
    assert out1.rigid_pose == out0.rigid_pose
    np.testing.assert_allclose(out1.encoder_positions, out0.encoder_positions, atol=0.0)
    with pytest.raises(ValueError, match="frame_load_schedule: times must be finite"):
        loaded.schedule_frame_load([(0.2, (0.0, 1.0, 0.0)), (0.1, (0.0, 0.0, 0.0))])
    with pytest.raises(ValueError, match="frame_compliance: must be 3 values >= 0"):
        Plant(MOM3, PlantParameters(frame_compliance=(-1.0, 0.0, 0.0)))
    with pytest.raises(ValueError, match="frame_compliance: must be 3 values on a 3-DOF machine"):
        Plant(MOM3, PlantParameters(frame_compliance=(1e-8,) * 6))


def test_internal_force_from_the_nominal_pseudo_inverse():
    """Forces distributed with the nominal model's pseudo-inverse load nothing when the
    geometry is exact, and fight when one leg is 2 % off (ARCHI §4.1)."""
    exact = Plant(ARCHI, PlantParameters(), initial_pose=POSE)
    out = exact.step(holding_forces(exact, jacobian_of=ARCHI.model))
    assert out.internal_force_norm < 1e-9
    wrong = Plant(ARCHI, PlantParameters(link_length_errors=(0.0, 0.0, 0.02, 0.0)), initial_pose=POSE)
    out = wrong.step(holding_forces(wrong, jacobian_of=ARCHI.model))
    assert out.internal_force_norm > 0.1          # ~0.8 N against ~250 N of weight carried
    # the internal force is what J_true^T cannot see
    np.testing.assert_allclose(wrong.machine.jacobian(wrong.x).T @ np.array(out.internal_force), 0.0, atol=1e-9)


def test_faults():
    plant = Plant(ARCHI, PlantParameters(encoder_resolution_m=0.0,
                                         faults=("0:no_force", "3:locked:0.01", "1:encoder_freeze:0.02")),
                  initial_pose=POSE)
    forces = [300.0, -200.0, 250.0, 100.0]
    readings = []
    for _ in range(40):
        out = plant.step(forces)
        readings.append(out.encoder_positions)
        assert out.applied_forces[0] == 0.0
    q3 = [plant.machine.inverse_kinematics(plant.x, check_limits=False)[3]]
    for _ in range(20):
        plant.step(forces)
        q3.append(plant.machine.inverse_kinematics(plant.x, check_limits=False)[3])
    assert np.ptp(q3) < 1e-6                       # the locked drive holds
    assert readings[-1][1] == readings[-15][1]     # the frozen encoder holds
    assert out.faults_active == ["0:no_force", "3:locked", "1:encoder_freeze"]
    # force balance: the reported forces (command + brake reaction on the locked drive)
    # are what accelerates the platform, A xddot + H = J^T f
    x, v = list(plant.x), list(plant.v)
    acc, _ = plant._acceleration(x, v, [0.0, -200.0, 250.0, 100.0])
    a, h, rows, _, _ = plant.dynamics.terms(x, v)
    lhs = np.array(a) @ np.array(acc) + np.array(h)
    out = plant.step(forces)
    np.testing.assert_allclose(np.array(rows).T @ np.array(out.applied_forces), lhs, atol=1e-6 * np.abs(lhs).max())


def test_three_locked_drives_hold_the_platform():
    plant = Plant(ARCHI, PlantParameters(faults=("0:locked:0.005", "1:locked:0.005", "2:locked:0.005")),
                  initial_pose=POSE)
    plant.v = [0.05, 0.0, 0.2]
    for _ in range(10):
        out = plant.step([0.0] * 4)
    assert out.stopped and "locked" in plant.stop_reason


def test_safe_stop_holds_the_platform():
    plant = Plant(ARCHI, PlantParameters(), initial_pose=POSE)
    plant.v = [0.1, 0.0, 0.5]
    plant.step([0.0] * 4)
    plant.safe_stop("command timeout")
    held = list(plant.x)
    for _ in range(10):
        out = plant.step([500.0] * 4)
    assert plant.x == held and out.stopped and out.applied_forces == [0.0] * 4
    assert plant.stop_reason == "command timeout"


def test_leaving_the_workspace_is_a_safe_stop():
    """Driven into the end stops or out of reach, the plant brakes at its last valid
    state and says why, instead of raising in the middle of a run."""
    plant = Plant(ARCHI, PlantParameters(), initial_pose=POSE)
    for _ in range(2000):
        out = plant.step([2000.0, 2000.0, 2000.0, 2000.0])
        if out.stopped:
            break
    assert out.stopped and "left the workspace" in plant.stop_reason
    plant.machine.inverse_kinematics(plant.x)            # the held pose is valid


def test_bad_input():
    plant = Plant(ARCHI, PlantParameters(), initial_pose=POSE)
    with pytest.raises(ValueError, match="drive forces: expected shape 4"):
        plant.step([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="drive forces: contains NaN"):
        plant.step([0.0, math.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="dt_s: must be"):
        Plant(ARCHI, PlantParameters(dt_s=0.0))
    with pytest.raises(ValueError, match="link_length_errors: must be 4 values"):
        Plant(ARCHI, PlantParameters(link_length_errors=(0.02,)))
    with pytest.raises(ValueError, match="faults: kind must be one of"):
        Fault.parse("1:melted", 4)
    with pytest.raises(ValueError, match=r"faults: drive must be in \[0, 3\]"):
        Fault.parse("7:locked", 4)


def test_scheduled_loads_apply_at_their_step_without_drift():
    """schedule_load counts steps: a load at t = 12.3455 s applies at step 12,346, where
    summing dt in floats would be one step off after ~12 s at 1 kHz."""
    plant = Plant(MOM3, PlantParameters(dt_s=0.001, encoder_resolution_m=0.0))
    plant.schedule_load([(0.0105, (1.0, 2.0, 3.0)), (12.3455, (0.0, 0.0, 5.0))])
    forces = holding_forces(plant)
    for _ in range(11):
        assert plant.load == [0.0, 0.0, 0.0]
        plant.step(forces)
    plant.step(forces)                                   # step 11 (t = 0.011 s): the first load
    assert plant.load == [1.0, 2.0, 3.0]
    plant.k = 12_345                                     # jump ahead (state untouched)
    plant.step(forces)
    assert plant.load == [1.0, 2.0, 3.0]
    plant.step(forces)
    assert plant.load == [0.0, 0.0, 5.0]
    with pytest.raises(ValueError, match="load_schedule: times must be"):
        plant.schedule_load([(1.0, (0, 0, 0)), (0.5, (0, 0, 0))])
    with pytest.raises(ValueError, match="load"):
        plant.schedule_load([(1.0, (0, float("nan"), 0))])


def test_command_efforts_come_in_drive_order_or_are_refused_with_the_reason():
    from pkm_common.cdr import JointStateData

    def command(names, effort):
        return JointStateData(0, "", tuple(names), (), (), tuple(effort))
    names = ["q1", "q2", "q3"]
    assert command_efforts(command(["q3", "q1", "q2"], [3.0, 1.0, 2.0]), names) == ([1.0, 2.0, 3.0], "")
    assert command_efforts(command([], [1.0, 2.0, 3.0]), names) == ([1.0, 2.0, 3.0], "")   # no names: in order
    assert command_efforts(command(["q1", "q2"], [1.0, 2.0]), names) == (
        None, "expected 3 efforts for ['q1', 'q2', 'q3'], got 2 for ['q1', 'q2']")
    assert command_efforts(command(["q1", "q9", "q3"], [1.0, 2.0, 3.0]), names)[0] is None  # not the drives
    assert command_efforts(command(names, [1.0, math.nan, 2.0]), names) == (None, "non-finite effort [1.0, nan, 2.0]")


def test_encoder_slip_offsets_one_reading_from_its_start():
    plant = Plant(load_machine("archi"), PlantParameters(faults=("1:encoder_slip:0.003:2e-4",)))
    healthy = Plant(load_machine("archi"))
    for k in range(6):
        out, ref = plant.step([100.0] * 4), healthy.step([100.0] * 4)
        # from its start on, only drive 1 reads 200 um more than the healthy machine's
        slip = [0.0, 2e-4 if k >= 3 else 0.0, 0.0, 0.0]
        np.testing.assert_allclose(np.subtract(out.encoder_positions, ref.encoder_positions), slip, atol=1e-12)
    assert Fault.parse("0:encoder_slip", 4).size == 1e-4
    with pytest.raises(ValueError, match="only encoder_slip takes a size"):
        Fault.parse("0:locked:0.1:1e-4", 4)
    with pytest.raises(ValueError, match=r"slip size must be in \[-0.01, 0.01\] m, got nan"):
        Fault.parse("0:encoder_slip:0.1:nan", 4)


def test_external_loads_are_bounded_and_a_refused_one_is_not_applied():
    plant = Plant(load_machine("archi"), PlantParameters(max_load_n=1000.0, max_load_nm=50.0))
    plant.set_load([900.0, -900.0, 40.0])
    with pytest.raises(ValueError, match=r"load: fx must be in \[-1000, 1000\] N \(max_load_n\), got 1e\+07"):
        plant.set_load([1e7, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"mz must be in \[-50, 50\] N m \(max_load_nm\), got 1e\+12"):
        plant.set_load([0.0, 0.0, 1e12])
    assert plant.load == [900.0, -900.0, 40.0]
    with pytest.raises(ValueError, match=r"load_schedule: fx must be in"):
        plant.schedule_load([(0.5, [1e12, 0.0, 0.0])])
    mom3 = Plant(load_machine("mom3"), PlantParameters(max_load_n=1000.0))
    with pytest.raises(ValueError, match=r"fz must be in \[-1000, 1000\] N"):
        mom3.set_load([0.0, 0.0, 2000.0])
    with pytest.raises(ValueError, match="max_load_n: must be"):
        PlantParameters(max_load_n=math.nan).validate(4)


BARS = (5.0e-5, -5.0e-5, 0.0, 3.0e-5, -2.0e-5, 0.0)       # config/machines/mom3_imperfect.yaml


def test_the_imperfect_delta_turns_its_tool_and_its_drives_read_the_bars():
    """MoM3 §4.1's imperfect case in the plant: with the bars of mom3_imperfect the tool
    carries the parasitic rotation of that machine at the plant's position (a second
    reader: pkm_kinematics' ParallelogramMachine loaded from its own config file), the
    drives read its actuator values, and the platform moves as the perfect Delta's under
    the same forces (the dynamics keep its J_m). Without bars: no rotation, as before."""
    imperfect = load_machine("mom3_imperfect").model
    params = dict(encoder_resolution_m=0.0)
    perfect = Plant(MOM3, PlantParameters(**params))
    plant = Plant(MOM3, PlantParameters(parallelogram_bar_errors_m=BARS, **params))
    forces = [150.0, -60.0, 20.0]
    for _ in range(50):
        out, ref = plant.step(forces), perfect.step(forces)
    assert out.rigid_pose == ref.rigid_pose and ref.tool_rotation is None
    p = np.array(out.rigid_pose)
    expected = imperfect.inverse_kinematics_full(p)
    np.testing.assert_allclose(np.array(out.tool_rotation).reshape(3, 3), expected.rotation, atol=1e-12)
    tilt = np.linalg.norm(imperfect.parasitic_rotation(p))
    assert 1e-4 < tilt < 5e-3                                   # mrad, what the encoders cannot see
    np.testing.assert_allclose(out.encoder_positions, expected.q, atol=1e-12)
    assert np.abs(np.array(out.encoder_positions) - ref.encoder_positions).max() > 1e-6
    with pytest.raises(ValueError, match=r"parallelogram_bar_errors_m: must be empty, or 6 values"):
        Plant(ARCHI, PlantParameters(parallelogram_bar_errors_m=BARS[:4] + (0.0, 0.0)))
    # the check asks the machine's task space (a Delta's: position), not a kind name
    PlantParameters(parallelogram_bar_errors_m=BARS).validate(3, MOM3.model.task_space)
    with pytest.raises(ValueError, match=r"parallelogram_bar_errors_m"):
        PlantParameters(parallelogram_bar_errors_m=BARS).validate(3, ARCHI.model.task_space)
    with pytest.raises(TypeError, match="space"):
        PlantParameters(parallelogram_bar_errors_m=BARS).validate(3, "translational")


@pytest.mark.parametrize("name", ["archi", "mom3", "orthoglide"])
def test_the_compiled_outputs_are_the_python_outputs_with_every_encoder_and_load_term(name):
    """The compiled step (rail_step.py) against the Python path with what the test
    below leaves out: encoder noise (the same draws), screw errors and offsets, a force
    limit the commands cross (saturation), the tool's and the frame's compliance under
    scheduled loads."""
    machine = load_machine(name)
    n = machine.model.n_legs
    probe = Plant(machine, PlantParameters())
    hold = min_two_norm(probe.machine.jacobian(probe.x), probe.dynamics.static_forces(probe.x))
    params = dict(link_length_errors=(0.01,) + (0.0,) * (n - 1), force_limit_n=float(np.abs(hold).max() + 60.0),
                  encoder_noise_m=2e-7,
                  seed=11, screw_errors_m=tuple(2e-6 * (i + 1) for i in range(n)), screw_error_period_m=0.05,
                  encoder_offsets_m=tuple(0.013 * (i - 1) for i in range(n)),
                  compliance=(1e-7, 2e-7, 3e-7), frame_compliance=(4e-8, 5e-8, 6e-8))
    compiled, python = Plant(machine, PlantParameters(**params)), Plant(machine, PlantParameters(**params))
    python.compiled_step = False
    for plant in (compiled, python):
        plant.schedule_load([(0.05, [30.0, -20.0, 1.0 if name == "archi" else 10.0]), (0.2, [0.0, 0.0, 0.0])])
        plant.schedule_frame_load([(0.1, [50.0, 0.0, 0.0])])
    rng = np.random.default_rng(5)
    saturated = 0
    for k in range(250):
        forces = (hold + rng.normal(0.0, 60.0, n)).tolist()
        a, b = compiled.step(forces), python.step(forces)
        assert (a, compiled.x, compiled.v, compiled.load) == (b, python.x, python.v, python.load), k
        saturated += any(a.saturated)
    assert saturated > 20 and a.tool_pose != a.rigid_pose and not a.stopped, (saturated, a)
    assert (a.internal_force_norm > 0.0) == (n > 3), a
    with pytest.raises(ValueError, match="drive forces"):
        compiled.step([math.nan] * n)


@pytest.mark.parametrize("name", ["archi", "mom3", "orthoglide"])
@pytest.mark.parametrize("substeps", [1, 3])
def test_the_compiled_step_is_the_python_step_to_the_bit(name, substeps):
    """Plant.step integrates a machine on rails in one compiled call
    (DynamicModel.semi_implicit_step); the Python path (_integrate, kept for rk4 and
    locked drives) is its reference: the same state and outputs at every step, under
    random forces about the holding forces, and the same stop where the machine is
    driven out of its workspace."""
    machine = load_machine(name)
    params = dict(substeps=substeps, link_length_errors=(0.01,) + (0.0,) * (machine.model.n_legs - 1),
                  force_limit_n=1e5)
    compiled, python = Plant(machine, PlantParameters(**params)), Plant(machine, PlantParameters(**params))
    python.compiled_step = False
    assert compiled.compiled_step
    rng = np.random.default_rng(3)
    hold = min_two_norm(compiled.machine.jacobian(compiled.x), compiled.dynamics.static_forces(compiled.x))
    for k in range(600):
        forces = (hold + rng.normal(0.0, 20.0, machine.model.n_legs)).tolist()
        a, b = compiled.step(forces), python.step(forces)
        assert (a, compiled.x, compiled.v) == (b, python.x, python.v), k
    # driven out of the workspace: on ARCHI the kernel's own failure (a leg that cannot
    # reach, named with the pose), on the others the end stop checked after it
    push = [3000.0 * (1 - 2 * (i % 2)) for i in range(machine.model.n_legs)]
    compiled = Plant(machine, PlantParameters(substeps=substeps, force_limit_n=1e5))
    python = Plant(machine, PlantParameters(substeps=substeps, force_limit_n=1e5))
    python.compiled_step = False
    for k in range(3000):
        a, b = compiled.step(push), python.step(push)
        assert (a, compiled.x, compiled.stop_reason) == (b, python.x, python.stop_reason), k
        if compiled.stopped:
            break
    expected = "is unreachable for leg" if name == "archi" else "reached its end stop"
    assert compiled.stopped and compiled.stop_reason.startswith("left the workspace:"), compiled.stop_reason
    assert expected in compiled.stop_reason, compiled.stop_reason


def test_encoder_noise_is_the_generators_stream_drawn_in_order():
    # Encoders.noise draws TAKES steps ahead (pkm_common.noise): the readings must still be
    # the seeded generator's normals in order, one per drive a step, across the blocks' edges
    from pkm_common.noise import TAKES
    from pkm_sim_hw.drives import Encoders
    steps, q = 2 * TAKES + 7, [0.1, 0.2, -0.3, 0.4]
    encoders = Encoders(0.0, 2e-7, seed=11, dt_s=1e-3)
    readings = np.array([encoders.quantise(q) for _ in range(steps)])
    expected = np.array(q) + 2e-7 * np.random.default_rng(11).standard_normal((steps, 4))
    assert np.array_equal(readings, expected)
