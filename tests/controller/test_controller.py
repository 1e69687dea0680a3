"""The controller core against the plant core (no ROS): every strategy settles and
tracks; the papers' results (ARCHI Fig. 12 fighting, projection and Cartesian control
not fighting, inf-norm lower peak force, MoM3 sensor-space accuracy under load);
the safety supervisor's trips; bad input and configuration."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.errors import SingularityError
from pkm_kinematics.planar import pair_force_map
from pkm_kinematics.task_space import PLANAR
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_trajectory.planner import Limits, Line, plan, plan_with_blending
from pkm_trajectory.program import gcode_segments
from pkm_controller.closed_loop import run
from pkm_controller.config import STRATEGIES, ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.strategies import REGISTRY, Law
from pkm_controller.reference import Reference

ARCHI = load_machine("archi")
MOM3 = load_machine("mom3")
ROOT = Path(__file__).resolve().parents[2]
ARCHI_HOME = ARCHI.model.home.tolist()
MOM3_HOME = MOM3.model.home.tolist()
LIMITS = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))
CONTROL_LIMIT_N = 2000.0                 # plant and controller force limit
ARCHI_STRATEGIES = ("joint_pid", "decentralized_projected", "cartesian_pid", "computed_torque")


def reference_of(samples) -> Reference:
    return Reference(samples.time_s, samples.position, samples.velocity, samples.acceleration)


def step_reference(home, axis, size):
    """A step: the hold pose, then 1 ms later the pose moved by ``size`` along ``axis``."""
    target = list(home)
    target[axis] += size
    return Reference([0.0, 0.001], [home, target])


def closed_loop(machine, strategy, steps, reference=None, plant_params=None, load=None, **config):
    plant = Plant(machine, plant_params or PlantParameters(force_limit_n=CONTROL_LIMIT_N))
    sensor = GoughSensorModel(machine.metrology) if machine.metrology is not None else None
    cfg = ControllerConfig(strategy=strategy, force_limit_n=CONTROL_LIMIT_N, **config)
    return run(machine, cfg, plant, steps, reference=reference, sensor=sensor, load=load)


CASES = [("archi", s) for s in ARCHI_STRATEGIES] + [("mom3", s) for s in STRATEGIES]


@pytest.mark.parametrize("machine_name, strategy", CASES)
def test_every_strategy_settles_a_step(machine_name, strategy):
    """A 1 mm step in x: error below 2 um (two encoder counts) 0.4 s later, with the
    integral action removing the gravity error, and no safety trip."""
    machine = ARCHI if machine_name == "archi" else MOM3
    home = ARCHI_HOME if machine_name == "archi" else MOM3_HOME
    core, log = closed_loop(machine, strategy, 500, step_reference(home, 0, 0.001))
    assert not core.stopped, core.stop_reason
    error = log.tool_error(machine_name == "archi")
    assert error[5] > 0.5e-3                  # it did have to move
    assert error[-1] < 2e-6, f"{strategy}: {error[-1] * 1e6:.2f} um left"


@pytest.mark.parametrize("machine_name, strategy", CASES)
def test_every_strategy_tracks_a_line(machine_name, strategy):
    """A jerk-limited 28 mm line (diagonal; the ARCHI nacelle turns 0.2 rad on the way):
    below 2 um at the end. During the move the model-based schemes (full A(x), H)
    stay within 0.3 mm; the model-free PIDs, whose feed-forward is only the diagonal
    mass, lag by up to 1 mm at 5 m/s^2 (a / omega^2 = 0.3 mm per axis, plus coupling)."""
    planar = machine_name == "archi"
    machine, home = (ARCHI, ARCHI_HOME) if planar else (MOM3, MOM3_HOME)
    end = [home[0] + 0.02, home[1] + 0.02, home[2] + (0.2 if planar else -0.0141)]
    samples = plan([Line(np.array(home), np.array(end))], LIMITS, translation_axes=2 if planar else 3)
    steps = int(samples.duration_s * 1000) + 400
    core, log = closed_loop(machine, strategy, steps, reference_of(samples))
    assert not core.stopped, core.stop_reason
    error = log.tool_error(planar)
    model_free = REGISTRY[strategy].law in (Law.JOINT_PID, Law.CARTESIAN_PID)
    bound = 1e-3 if model_free else 3e-4
    assert error.max() < bound, f"{strategy}: {error.max() * 1e6:.0f} um"
    assert error[-1] < 2e-6
    np.testing.assert_allclose(log.tool[-1], end, atol=2e-6)


ARCHI_2PCT = PlantParameters(force_limit_n=CONTROL_LIMIT_N, link_length_errors=(0.0, 0.0, 0.02, 0.0))


def test_joint_pid_fights_with_a_two_percent_leg_error():
    """ARCHI Fig. 12: independent joint PIDs with a 2 % error on one leg do not
    converge: the drives fight (internal force, null space of the TRUE J^T) up to
    saturation, and the supervisor trips after saturation_trip_s. Without the error
    the same controller holds with a negligible internal force."""
    core, log = closed_loop(ARCHI, "joint_pid", 1000, plant_params=ARCHI_2PCT, saturation_trip_s=0.5)
    internal = np.array(log.internal_force_norm_n)
    forces = np.abs(np.array(log.forces))
    assert internal[200:499].min() > 0.9 * CONTROL_LIMIT_N
    assert forces[100:499].max() == CONTROL_LIMIT_N
    assert core.stopped and "saturated" in core.stop_reason
    exact, exact_log = closed_loop(ARCHI, "joint_pid", 1000)
    assert not exact.stopped and max(exact_log.internal_force_norm_n[200:]) < 0.05 * CONTROL_LIMIT_N


@pytest.mark.parametrize("strategy", ["decentralized_projected", "cartesian_pid", "computed_torque"])
def test_projected_and_cartesian_control_do_not_fight(strategy):
    """Sliding Star eq. 8 and the Cartesian schemes under the same 2 % error: internal
    force below 1 % of the drive limit, and the forces converge (the mean over the
    last 0.5 s equals the mean over the 0.5 s before it within 5 N)."""
    core, log = closed_loop(ARCHI, strategy, 2000, plant_params=ARCHI_2PCT)
    assert not core.stopped, core.stop_reason
    internal = np.array(log.internal_force_norm_n)
    assert internal[200:].max() < 0.01 * CONTROL_LIMIT_N
    forces = np.array(log.forces)
    np.testing.assert_allclose(forces[-500:].mean(axis=0), forces[-1000:-500].mean(axis=0), atol=5.0)
    assert np.abs(forces[-500:]).max() < 0.2 * CONTROL_LIMIT_N


def test_the_fig9_variant_stops_the_windup_but_not_the_proportional_fight():
    """Sliding Star Fig. 9 (the integral component projected on range(J), the variant
    run on the lab model) under the same 2 % error: no wind-up, so no saturation and a
    steady internal force (the last 0.5 s as the 0.5 s before), but the proportional
    and derivative terms still fight: a constant internal force of about half the
    drive limit, against under 1 % with the whole command projected (eq. 8)."""
    core, log = closed_loop(ARCHI, "decentralized_integral_projected", 2000, plant_params=ARCHI_2PCT)
    assert not core.stopped, core.stop_reason
    internal = np.array(log.internal_force_norm_n)
    assert abs(internal[-500:].mean() - internal[-1000:-500].mean()) < 5.0
    assert 0.3 * CONTROL_LIMIT_N < internal[-500:].mean() < 0.8 * CONTROL_LIMIT_N
    assert core.supervisor.saturation_count == 0


@pytest.fixture(scope="module")
def archi_test_motion():
    program = (ROOT / "config" / "programs" / "archi_test_motion.nc").read_text()
    segments = gcode_segments(program, PLANAR, ARCHI_HOME)
    return reference_of(plan_with_blending(segments, LIMITS, 0.0, 1000.0, translation_axes=2))


def test_inf_norm_lowers_the_peak_drive_force_on_the_archi_test_motion(archi_test_motion):
    """ARCHI §4.5 Fig. 17-18: minimising the infinity norm of the drive forces gives a
    lower peak force than the pseudo-inverse on the test motion; tracking is the same."""
    steps = int(archi_test_motion.duration_s * 1000) + 100
    peaks, errors = {}, {}
    for method in ("pseudo_inverse", "inf_norm"):
        core, log = closed_loop(ARCHI, "computed_torque", steps, archi_test_motion, distribution=method)
        assert not core.stopped, core.stop_reason
        peaks[method] = np.abs(np.array(log.forces)).max()
        errors[method] = log.tool_error(True).max()
    assert peaks["inf_norm"] < 0.9 * peaks["pseudo_inverse"], peaks
    assert errors["inf_norm"] == pytest.approx(errors["pseudo_inverse"], rel=0.2, abs=2e-6)


def test_sensor_space_keeps_the_tool_on_target_under_load():
    """MoM3 §7 Fig. 19: a 110 N then 140 N load on the tool deflects the structure
    (compliance 0.7 um/N, MoM3: ~70-80 um under 110 N) where the drive encoders cannot
    see it. Encoder-based cartesian_pid shows the full deflection; sensor_space keeps the
    tool within the metrology resolution (1 um) and measured_space likewise."""
    params = PlantParameters(force_limit_n=CONTROL_LIMIT_N, compliance=(7e-7, 7e-7, 7e-7))

    def load(t):
        return [0.0, 0.0, -110.0] if t < 1.0 else [0.0, 0.0, -140.0]

    errors = {}
    for strategy in ("cartesian_pid", "sensor_space", "measured_space"):
        core, log = closed_loop(MOM3, strategy, 2000, plant_params=params, load=load)
        assert not core.stopped, core.stop_reason
        e = log.tool_error(False)
        errors[strategy] = (e[900:1000].max(), e[1900:].max())
    assert errors["cartesian_pid"][0] == pytest.approx(7e-7 * 110, rel=0.05)
    assert errors["cartesian_pid"][1] == pytest.approx(7e-7 * 140, rel=0.05)
    for strategy in ("sensor_space", "measured_space"):
        assert max(errors[strategy]) < 1.5e-6, (strategy, errors[strategy])


# ---------------------------------------------------------------- safety
def test_a_drive_without_force_is_dropped_and_the_sub_machine_goes_on():
    """Drive q3 loses its force at 0.2 s: detected from its reported force within the
    mismatch window, the machine continues on J_124 and still settles a step."""
    params = PlantParameters(force_limit_n=CONTROL_LIMIT_N, faults=("2:no_force:0.2",))
    ref = Reference([0.0, 0.4, 0.401], [ARCHI_HOME, ARCHI_HOME, [ARCHI_HOME[0] + 0.001, *ARCHI_HOME[1:]]])
    core, log = closed_loop(ARCHI, "computed_torque", 900, ref, plant_params=params, distribution="inf_norm")
    assert not core.stopped, core.stop_reason
    assert core.supervisor.active == [0, 1, 3] and "continuing on J_124" in " ".join(core.supervisor.faults)
    assert all(f[2] == 0.0 for f in log.forces[215:])
    assert log.tool_error(True)[-1] < 2e-6
    level, message, values = core.status()
    assert level == 1 and values["active_drives"] == "q1,q2,q4"


def test_a_failed_drive_stops_the_machine_when_not_allowed_to_continue():
    params = PlantParameters(force_limit_n=CONTROL_LIMIT_N, faults=("2:no_force:0.1",))
    core, _ = closed_loop(ARCHI, "cartesian_pid", 300, plant_params=params, continue_on_drive_failure=False)
    assert core.stopped and "drive q3 failed (no force)" in core.stop_reason


def test_a_locked_drive_stops_the_machine():
    """A brake or jam: the drive reports a force it was not commanded -> safe stop."""
    params = PlantParameters(force_limit_n=CONTROL_LIMIT_N, faults=("1:locked:0.1",))
    ref = Reference([0.0, 0.1, 0.3], [ARCHI_HOME, ARCHI_HOME, [ARCHI_HOME[0] + 0.01, *ARCHI_HOME[1:]]])
    core, log = closed_loop(ARCHI, "computed_torque", 400, ref, plant_params=params)
    assert core.stopped and "drive q2 failed (reports" in core.stop_reason
    assert log.forces[-1] == [0.0] * 4


def test_a_failed_drive_near_a_sub_machine_singularity_stops():
    """ARCHI Fig. 10: J_124 is singular at theta = -150 deg and 19.47 deg; at 19 deg it
    cannot take over, so the failure of q3 stops the machine."""
    pose = [1.0, -0.4, np.radians(19.0)]
    params = PlantParameters(force_limit_n=CONTROL_LIMIT_N, faults=("2:no_force:0.05",))
    plant = Plant(ARCHI, params, initial_pose=pose)
    core, _ = run(ARCHI, ControllerConfig(strategy="computed_torque", max_condition=100.0), plant, 200)
    assert core.stopped and "J_124 too close to singular" in core.stop_reason


def test_following_error_trips():
    """A 5 mm step with a 1 mm following-error limit."""
    core, log = closed_loop(ARCHI, "computed_torque", 100, step_reference(ARCHI_HOME, 0, 0.0049),
                            following_error_m=0.001, start_tolerance_m=0.0005)
    assert core.stopped and "following error 4.9" in core.stop_reason
    assert log.forces[-1] == [0.0] * 4


def test_workspace_and_singularity_margin_trip():
    plant = Plant(ARCHI, PlantParameters(), initial_pose=[1.45, -0.4, 0.8])
    core, _ = run(ARCHI, ControllerConfig(strategy="cartesian_pid"), plant, 3)
    assert core.stopped and core.stop_reason.startswith("workspace: x = 1.45")
    core, _ = closed_loop(ARCHI, "cartesian_pid", 3, max_condition=2.0)
    assert core.stopped and core.stop_reason.startswith("singularity margin: condition number")


@pytest.mark.parametrize("q, qdot, message", [
    ([1.0, 2.0, float("nan"), 0.5], [0.0] * 4, r"position\[2\] \(q3\) is nan"),
    ([1.0, 2.0, 0.5], [0.0] * 4, "position has 3 values, expected 4"),
    ([1.0, 2.0, 0.5, 0.6], [0.0, float("inf"), 0.0, 0.0], r"velocity\[1\] \(q2\) is inf"),
    # each finite, their sum not (it raised StopIteration out of the controller)
    ([1.0, 1.7e308, 0.5, 1.7e308], [0.0] * 4, r"position\[1\] \(q2\) is 1.7e\+308"),
])
def test_a_bad_state_is_refused_and_the_controller_stops(q, qdot, message):
    core = ControllerCore(ARCHI, ControllerConfig())
    forces = core.update(0, q, qdot)
    assert forces == [0.0] * 4 and core.stopped
    assert re.search(message, core.stop_reason), core.stop_reason
    assert core.update(1_000_000, [0.0] * 4, [0.0] * 4) == [0.0] * 4        # stays stopped


def test_a_singular_measured_pose_stops_the_controller_naming_it(monkeypatch):
    """J_m, the task velocity and A, H come from DynamicModel.measured_state; when it
    refuses the measured pose the controller trips saying so, it does not raise."""
    core = ControllerCore(ARCHI, ControllerConfig(strategy="computed_torque"))

    def singular(x, qdot):
        raise SingularityError("leg q2 is perpendicular to its rail (serial singularity)")

    monkeypatch.setattr(core.dynamics, "measured_state", singular)
    monkeypatch.setattr(core.dynamics, "encoder_state", None)          # not in one call with the kinematics
    monkeypatch.setattr(core, "compiled", None)                      # nor in the compiled prepare
    assert core.update(0, *_state_at(ARCHI_HOME)) == [0.0] * 4
    assert core.stopped
    assert core.stop_reason == "kinematics at the measured pose: leg q2 is perpendicular to its rail (serial singularity)"


@pytest.mark.parametrize("strategy", ["joint_pid", "computed_torque"])
def test_a_drive_beyond_its_joint_limit_trips_naming_it(strategy):
    """The joint limits come first among the per-cycle limits, on the Python (joint)
    and the compiled (Cartesian) path alike."""
    core = ControllerCore(MOM3, ControllerConfig(strategy=strategy))
    q = MOM3.model.inverse_kinematics(MOM3_HOME).tolist()
    core.update(0, q, [0.0] * 3)
    assert not core.stopped
    q[1] = 1.86                                           # limits [1.15, 1.85] m
    assert core.update(1_000_000, q, [0.0] * 3) == [0.0] * 3
    assert core.stop_reason == "joint limit: drive q2 at 1.86 m outside [1.15, 1.85] m"


def test_a_non_finite_model_wrench_stops_the_controller_naming_it(monkeypatch):
    """A NaN from the dynamic model reaches the wrench: refused before any drive moves."""
    core = ControllerCore(ARCHI, ControllerConfig(strategy="computed_torque"))
    core.update(0, *_state_at(ARCHI_HOME))
    measured_state = core.dynamics.measured_state

    def nan_gravity(x, qdot):
        a, h, rows, v = measured_state(x, qdot)
        return a, (h[0], math.nan, h[2]), rows, v

    monkeypatch.setattr(core.dynamics, "measured_state", nan_gravity)
    monkeypatch.setattr(core.dynamics, "encoder_state", None)          # not in one call with the kinematics
    monkeypatch.setattr(core, "compiled", None)                      # nor in the compiled prepare
    assert core.update(1_000_000, *_state_at(ARCHI_HOME)) == [0.0] * 4
    assert core.stop_reason.startswith("computed_torque: wrench: contains NaN or infinite values: [")


def test_a_finite_wrench_whose_sum_overflows_is_distributed_and_clamped(monkeypatch):
    """Each component finite, their sum not: still a wrench (the checks are per
    component), distributed, and the drives get the clamped forces, saturation
    counted, the machine not tripped for it."""
    core = ControllerCore(ARCHI, ControllerConfig(strategy="computed_torque"))
    core.update(0, *_state_at(ARCHI_HOME))
    measured_state = core.dynamics.measured_state

    def huge(x, qdot):
        a, _, rows, v = measured_state(x, qdot)
        return a, (1e308, 1e308, 0.0), rows, v

    monkeypatch.setattr(core.dynamics, "measured_state", huge)
    monkeypatch.setattr(core.dynamics, "encoder_state", None)          # not in one call with the kinematics
    monkeypatch.setattr(core, "compiled", None)                      # nor in the compiled prepare
    forces = core.update(1_000_000, *_state_at(ARCHI_HOME))
    assert not core.stopped, core.stop_reason
    assert max(abs(f) for f in forces) == core.config.force_limit_n and core.supervisor.saturation_count == 1


def test_missing_metrology_stops_the_measured_space_controller():
    core = ControllerCore(MOM3, ControllerConfig(strategy="measured_space"))
    q = MOM3.model.inverse_kinematics(MOM3_HOME).tolist()
    core.update(0, q, [0.0] * 3, metrology_pose=None)
    assert core.stopped and "metrology/pose: missing" in core.stop_reason


def _mom3_struts(pose):
    sensor = GoughSensorModel(MOM3.metrology)
    return sensor.true_lengths(np.array(pose), np.eye(3)).tolist()


def test_a_cycle_prepared_on_the_state_completes_on_the_struts():
    """The node's split: prepare on drives/state, complete when metrology/struts come.
    Bad readings at complete trip naming the stream; complete without a prepared
    cycle is a programming error; a stopped controller answers zeros at prepare."""
    q = MOM3.model.inverse_kinematics(MOM3_HOME).tolist()
    core = ControllerCore(MOM3, ControllerConfig(strategy="sensor_space"))
    assert core.prepare(0, q, [0.0] * 3) is True
    forces = core.complete(struts=_mom3_struts(MOM3_HOME))
    assert not core.stopped and len(forces) == 3 and core.cycles == 1
    with pytest.raises(RuntimeError, match="no cycle prepared"):
        core.complete(struts=_mom3_struts(MOM3_HOME))
    assert core.prepare(1_000_000, q, [0.0] * 3) is True
    assert core.complete(struts=[0.8] * 5) == [0.0] * 3
    assert core.stopped and core.stop_reason.startswith("metrology/struts: expected 6 finite strut lengths")
    assert core.prepare(2_000_000, q, [0.0] * 3) is False and core.last_command == [0.0] * 3
    assert core.complete(struts=_mom3_struts(MOM3_HOME)) == [0.0] * 3


def test_trajectories_must_start_at_the_current_reference():
    core, _ = closed_loop(ARCHI, "computed_torque", 5)
    far = Reference([0.0, 1.0], [[1.1, -0.4, 0.785], [1.2, -0.4, 0.785]])
    with pytest.raises(ValueError, match="trajectory refused: it starts at .* 100.000 mm"):
        core.set_trajectory(far)
    near = Reference([0.0, 1.0], [ARCHI_HOME, [1.01, -0.4, 0.785]])
    core.set_trajectory(near)
    core.update(6_000_000, *_state_at(ARCHI_HOME))
    with pytest.raises(ValueError, match="another trajectory is running"):
        core.set_trajectory(near)


def test_a_trajectory_received_before_the_first_state_is_checked_then():
    """Set before any state: checked against the measured pose at the first cycle;
    a far one is refused there (reported in the faults), the machine holds."""
    core = ControllerCore(ARCHI, ControllerConfig())
    core.set_trajectory(Reference([0.0, 1.0], [[1.1, -0.4, 0.785], [1.2, -0.4, 0.785]]))
    core.update(0, *_state_at(ARCHI_HOME))
    assert not core.stopped and core.mode == "holding" and "trajectory refused" in core.supervisor.faults[0]
    core = ControllerCore(ARCHI, ControllerConfig())
    core.set_trajectory(Reference([0.0, 1.0], [ARCHI_HOME, [1.01, -0.4, 0.785]]))
    core.update(0, *_state_at(ARCHI_HOME))
    assert core.mode == "tracking" and core.reference.duration_s == 1.0


def _state_at(pose):
    return ARCHI.model.inverse_kinematics(pose).tolist(), [0.0] * 4


@pytest.mark.parametrize("field, value, message", [
    ("strategy", "magic", "strategy: must be one of"),
    ("distribution", "two_arm", "two_arm only on a planar machine"),
    ("bandwidth_hz", 500.0, r"bandwidth_hz: must be in \(0, 100\] Hz"),
    ("integral_time_s", 0.001, r"integral_time_s: must be 0, or in \(0.003979, inf\) s"),
    ("prestress_n", 10.0, "prestress_n: must be 0, or finite on a machine with one redundant drive"),
    ("force_limit_n", -1.0, r"force_limit_n: must be in \(0, inf\) N"),
    # a trajectory accepted 4.24 mm off the reference made it jump 4.24 mm in a step: the
    # tolerance was 20 mm against a 10 mm following-error bound
    ("start_tolerance_m", 0.02, r"start_tolerance_m: must be in \[0, 0.01\) m \(below following_error_m\)"),
    ("start_tolerance_rad", 0.05, r"start_tolerance_rad: must be in \[0, 0.05\) rad"),
])
def test_invalid_configuration_names_the_field(field, value, message):
    with pytest.raises(ValueError, match=message):
        ControllerCore(MOM3, ControllerConfig(**{field: value}))


def test_metrology_strategies_need_a_metrology_section():
    with pytest.raises(ValueError, match="strategy: sensor_space needs a machine with a 'metrology' section"):
        ControllerCore(load_machine("sliding_star"), ControllerConfig(strategy="sensor_space"))
    with pytest.raises(ValueError, match="unknown controller parameter"):
        ControllerConfig.from_dict({"kp": 1.0})


@pytest.mark.parametrize("name", ["archi", "mom3"])
def test_shipped_controller_configs_are_valid(name):
    """config/controller/<name>.yaml builds a controller for its machine; every key is
    a controller or node parameter."""
    import yaml

    from pkm_controller.configuration import NODE_PARAMETERS
    params = yaml.safe_load((ROOT / "config" / "controller" / f"{name}.yaml").read_text())["/**"]["ros__parameters"]
    node_keys = set(NODE_PARAMETERS) | {"autostart"}
    core = ControllerCore(load_machine(params["machine"]),
                          ControllerConfig.from_dict({k: v for k, v in params.items() if k not in node_keys}))
    assert core.config.strategy == params["strategy"]


def _late_commands_loop(flag_held: bool, steps: int = 400, late=lambda k: 2 <= k % 60 < 10, faults=(),
                        reference=None, arrive_late: bool = False):
    """ARCHI following a reference while some of its commands miss the plant's cycle
    (``late(k)``; realtime overload), as sim_hw in real time: at each tick the plant
    applies the latest command it has; one that missed its tick arrives after it and
    is applied at the next (``arrive_late``) or never (too old, refused), so the forces
    a state reports answer an older command than the controller's last; with
    ``flag_held`` the state says which (the status word)."""
    plant = Plant(ARCHI, PlantParameters(force_limit_n=CONTROL_LIMIT_N, faults=faults))
    core = ControllerCore(ARCHI, ControllerConfig(strategy="cartesian_pid", force_limit_n=CONTROL_LIMIT_N))
    core.set_trajectory(reference or step_reference(ARCHI_HOME, 0, 0.001))
    out, latest, latest_stamp, held = plant.output(), [0.0] * 4, 0, False
    for k in range(steps):
        stamp = out.stamp_ns
        forces = core.update(out.stamp_ns, out.encoder_positions, out.encoder_velocities, out.applied_forces,
                             held=latest_stamp if held and flag_held else None)
        held = late(k)                               # this command misses its tick...
        if not held:
            latest, latest_stamp = forces, stamp
        out = plant.step(latest)
        if held and arrive_late:                     # ...and arrives after it: applied at the next
            latest, latest_stamp = forces, stamp
        if core.stopped:
            break
    return core, out.time_s


def test_a_held_setpoint_is_not_taken_for_a_failed_drive():
    """Realtime overload: the plant says in the state's status word which command it
    applied again (sim_hw, setpoint_held:<stamp>); the drive supervision compares the
    reported forces with that one. Without it the same run trips as a drive failure:
    a consequence of missed deadlines reported as a broken drive."""
    core, _ = _late_commands_loop(flag_held=True)
    assert not core.stopped, core.stop_reason
    unflagged, _ = _late_commands_loop(flag_held=False)
    assert unflagged.stopped and str(unflagged.stop_cause) == "drive_failure", unflagged.stop_reason


def test_a_locked_drive_is_found_while_every_setpoint_is_held():
    """A controller one cycle late every time from 20 ms on (the sync error counter
    off): every state is a held one, each answering the command before the last. The
    supervision compares each reported force with the command the plant applied, so a
    drive braked at 0.1 s in motion is found within the mismatch window (skipping the
    held cycles, as first done, never checked a drive again)."""
    always = lambda k: k >= 20                               # noqa: E731
    moving = Reference([0.0, 0.3, 0.4], [ARCHI_HOME, [ARCHI_HOME[0] + 0.03, *ARCHI_HOME[1:]],
                                          [ARCHI_HOME[0] + 0.03, *ARCHI_HOME[1:]]])     # braked in motion
    core, _ = _late_commands_loop(flag_held=True, late=always, reference=moving, arrive_late=True)
    assert not core.stopped, core.stop_reason
    core, t_stop = _late_commands_loop(flag_held=True, late=always, faults=("2:locked:0.1",), reference=moving,
                                       arrive_late=True)
    assert core.stopped and str(core.stop_cause) == "drive_failure" and "drive q3" in core.stop_reason
    assert 0.1 < t_stop <= 0.1 + 0.008, t_stop


def test_two_arm_with_gravity_sets_the_nacelle_internal_force_of_archi_4_3_2():
    """distribution two_arm_gravity: the arms' forces on the nacelle satisfy
    (f1 - f2) . n = M_n G sin(theta) (ARCHI §4.3.2; M_n 25 kg, g = (0, -9.81) in
    config/machines/archi.yaml), two_arm sets it to 0 (§4.3.1); both produce the
    controller's wrench (J^T f the same)."""
    pose = [1.0, -0.4, 1.1]
    model = ARCHI.model
    force_map, jf = pair_force_map(model, pose)
    out = {}
    for distribution in ("two_arm", "two_arm_gravity"):
        core = ControllerCore(ARCHI, ControllerConfig(strategy="computed_torque", distribution=distribution))
        q = model.inverse_kinematics(pose).tolist()
        forces = np.array(core.update(0, q, [0.0] * 4))
        assert not core.stopped, core.stop_reason
        out[distribution] = (jf @ np.linalg.solve(force_map, forces), model.jacobian(pose).T @ forces)
    assert out["two_arm"][0][3] == pytest.approx(0.0, abs=1e-6)
    assert out["two_arm_gravity"][0][3] == pytest.approx(25.0 * 9.81 * math.sin(1.1), rel=1e-9)
    np.testing.assert_allclose(out["two_arm"][1], out["two_arm_gravity"][1], atol=1e-6)


@pytest.mark.parametrize("fk, tolerance", [("integrated", 1e-6), ("integrated_euler", 5e-5)])
def test_the_integrated_forward_kinematics_tracks_like_newton(fk, tolerance):
    """forward_kinematics integrated / integrated_euler (Sliding Star §3.1): ARCHI
    follows a 20 mm line in 0.1 s with its encoder pose carried by the increments; the
    tool follows the Newton run's within the integration's error; a bad name is refused."""
    ref = Reference([0.0, 0.1, 0.3], [ARCHI_HOME, [ARCHI_HOME[0] + 0.02, *ARCHI_HOME[1:]],
                                      [ARCHI_HOME[0] + 0.02, *ARCHI_HOME[1:]]])
    _, newton = closed_loop(ARCHI, "computed_torque", 300, ref)
    core, integrated = closed_loop(ARCHI, "computed_torque", 300, ref, forward_kinematics=fk)
    assert not core.stopped, core.stop_reason
    gap = np.abs(np.array(integrated.tool)[:, :2] - np.array(newton.tool)[:, :2]).max()
    assert 0.0 < gap < tolerance
    with pytest.raises(ValueError, match=r"forward_kinematics: must be one of \['newton', 'integrated'"):
        ControllerCore(ARCHI, ControllerConfig(forward_kinematics="euler"))


def test_two_arm_needs_two_leg_pairs():
    """Sliding Star has 4 drives on a planar machine, but its legs do not pair up on two
    platform points: two_arm is refused at configuration, not at the first cycle."""
    star = load_machine("sliding_star")
    for distribution in ("two_arm", "two_arm_gravity"):
        with pytest.raises(ValueError, match=f"distribution: {distribution} needs two pairs of legs"):
            ControllerCore(star, ControllerConfig(distribution=distribution))


def test_fk_resync_cycles_puts_a_newton_solution_every_n_cycles():
    """forward_kinematics integrated_euler with fk_resync_cycles 5: the encoder pose is
    Newton's exactly at cycles 0, 5, 10, and the integrated one in between."""
    core = ControllerCore(ARCHI, ControllerConfig(strategy="computed_torque", forward_kinematics="integrated_euler",
                                                  fk_resync_cycles=5))
    model = ARCHI.model
    exact = []
    for k in range(12):
        pose = [ARCHI_HOME[0] + 2e-6 * k, ARCHI_HOME[1] + 1e-6 * k * k, ARCHI_HOME[2] + 1e-5 * k]
        q = model.inverse_kinematics(pose).tolist()
        previous = core.estimator.pose
        core.update(1_000_000 * k, q, [0.0] * 4)
        assert not core.stopped, core.stop_reason
        newton = list(model.forward_kinematics_floats(q, previous))
        exact.append(core.estimator.pose == newton)
    assert exact == [k % 5 == 0 for k in range(12)]


def test_a_trajectory_too_far_from_the_machine_is_refused_and_it_holds_where_it_is():
    """ARCHI with leg-length errors of ~1 % starts 11.6 mm from the program's start in
    the nominal model. The trajectory was accepted (20 mm start tolerance), the
    reference jumped 11.6 mm and the following error stopped the machine in its first
    cycle; now it is refused (5 mm, below the following-error bound) and the machine
    holds. Its reference (controller/reference, against which the report measures the
    tracking error) is where the machine is, not (0, 0, 0): a study's report said
    1.077 m of tracking error, |(1, -0.4)|, for a machine that never moved."""
    from pkm_controller.closed_loop import run
    from pkm_controller.reference import Reference
    from pkm_sim_hw.plant import Plant, PlantParameters
    from pkm_trajectory.planner import Limits, Line, plan
    machine = load_machine("archi")
    home = machine.model.home
    samples = plan([Line(np.array(home), np.array(home) + [0.05, 0.0, 0.0])],
                   Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0)), translation_axes=2)
    plant = Plant(machine, PlantParameters(link_length_errors=(-0.0063, 0.0008, -0.013, -0.0004)))
    core, log = run(machine, ControllerConfig(strategy="joint_pid"), plant, 3,
                    reference=Reference(samples.time_s, samples.position, samples.velocity, samples.acceleration))
    assert not core.stopped and core.mode == "holding", core.stop_reason
    assert any("trajectory refused" in f and "11.6" in f and "start_tolerance_m 0.005" in f for f in core.supervisor.faults), \
        core.supervisor.faults
    assert np.allclose(log.reference[0][:2], home[:2], atol=0.05) and abs(log.reference[0][0]) > 0.5


def _one_cycle_late_loop(delay_cycles: int, faults=(), steps: int = 400):
    """ARCHI on drives that apply each command a cycle after the state that follows it
    (CiA 402 drives with synchronous RPDOs: the command answering state k acts from
    state k+1 to k+2), following a 1 mm step; a drive's force 5 N off its command for
    5 cycles is a failed drive (a tight drive_mismatch_n, so that the lag shows)."""
    plant = Plant(ARCHI, PlantParameters(force_limit_n=CONTROL_LIMIT_N, faults=faults))
    core = ControllerCore(ARCHI, ControllerConfig(strategy="cartesian_pid", force_limit_n=CONTROL_LIMIT_N,
                                                  drive_mismatch_n=5.0, actuation_delay_cycles=delay_cycles))
    core.set_trajectory(step_reference(ARCHI_HOME, 0, 0.001))
    out, pending = plant.output(), [0.0] * 4
    for _ in range(steps):
        forces = core.update(out.stamp_ns, out.encoder_positions, out.encoder_velocities, out.applied_forces)
        out = plant.step(pending)                    # the command of the state before
        pending = forces
        if core.stopped:
            break
    return core, out.time_s


def test_the_drive_supervision_compares_with_the_command_a_delayed_drive_applied():
    """actuation_delay_cycles: the forces a state reports answer the command before the
    last; compared with the last, a moving machine's drives look failed; compared with
    the right one, nothing trips, and a drive braked at 0.1 s is still found."""
    core, _ = _one_cycle_late_loop(1)
    assert not core.stopped, core.stop_reason
    confused, _ = _one_cycle_late_loop(0)
    assert confused.stopped and str(confused.stop_cause) == "drive_failure", confused.stop_reason
    core, t_stop = _one_cycle_late_loop(1, faults=("2:locked:0.1",))
    assert core.stopped and str(core.stop_cause) == "drive_failure" and "drive q3" in core.stop_reason
    assert 0.1 < t_stop <= 0.1 + 0.010, t_stop
