"""The encoder state of a cycle in one compiled call (DynamicModel.encoder_state:
the forward kinematics of the readings and the measured state there) against the two
calls it replaces (the solver's forward_kinematics_floats, then measured_state): the
same commands every cycle, bit for bit, the same trips and the same errors."""

import numpy as np
import pytest

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.dynamics import dynamic_model
from pkm_kinematics.errors import KinematicsError
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_trajectory.planner import Limits, Line, plan
import pkm_controller.pose_estimation as pose_estimation
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.reference import Reference

LIMITS = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))


def move(machine_name, strategy, faults=(), link_length_errors=(), **config):
    machine = load_machine(machine_name)
    planar = machine.kind == "planar"
    home = machine.model.home.tolist()
    end = [home[0] + 0.04, home[1] + 0.02, home[2] + (0.1 if planar else 0.0)]
    samples = plan([Line(np.array(home), np.array(end))], LIMITS, translation_axes=2 if planar else 3)
    plant = Plant(machine, PlantParameters(force_limit_n=2000.0, faults=faults, encoder_noise_m=1e-7, seed=5,
                                           link_length_errors=link_length_errors))
    ref = Reference(samples.time_s, samples.position, samples.velocity, samples.acceleration)
    sensor = GoughSensorModel(machine.metrology) if machine.metrology is not None else None
    return run(machine, ControllerConfig(strategy=strategy, force_limit_n=2000.0, **config), plant,
               int(samples.duration_s * 1000) + 100, reference=ref, sensor=sensor)


CASES = [("archi", "computed_torque", (), ()), ("archi", "sensor_space", (), ()),
         ("archi", "decentralized_projected", (), (0.0, 0.0, 0.02, 0.0)),        # ARCHI §4.1's 2 % leg
         ("mom3", "cartesian_pid", (), ()), ("orthoglide", "joint_pid", (), ()),
         ("archi", "computed_torque", ("2:encoder_slip:0.1:3e-4",), ())]           # a trip


@pytest.mark.parametrize("machine_name, strategy, faults, errors", CASES)
def test_one_call_is_the_two_calls_it_replaces(machine_name, strategy, faults, errors, monkeypatch):
    fused_core, fused = move(machine_name, strategy, faults, errors)
    assert fused_core.dynamics.encoder_state is not None
    monkeypatch.setattr(pose_estimation, "FUSE_ENCODER_STATE", False)
    core, log = move(machine_name, strategy, faults, errors)
    assert (core.stopped, core.stop_reason) == (fused_core.stopped, fused_core.stop_reason)
    assert len(log.forces) == len(fused.forces) > 50
    assert np.array_equal(np.array(log.forces), np.array(fused.forces))
    assert core.estimator.pose == fused_core.estimator.pose


@pytest.mark.parametrize("machine_name", ["archi", "mom3"])
def test_what_the_call_refuses_is_named_by_the_interpreted_path(machine_name):
    machine = load_machine(machine_name)
    dynamics = dynamic_model(machine)
    q = np.array([0.0, 5.0, -5.0, 0.0][:machine.model.n_legs])        # legs that cannot close
    assert dynamics.encoder_state(q, None, np.zeros(machine.model.n_legs)) == (None, None)
    with pytest.raises(KinematicsError, match="cannot"):
        machine.model.forward_kinematics_floats(q, None)


def strut_move(machine_name, strategy, faults=(), link_length_errors=()):
    """A six-DOF move of a hexapod through the SE(3) plant (test_controller_spatial's)."""
    from pkm_sim_hw.strut_plant import StrutPlant
    machine = load_machine(machine_name)
    home = machine.model.home
    t = np.linspace(0.0, 0.6, 121)
    s, ds, dds = 0.5 - 0.5 * np.cos(np.pi / 0.6 * t), 0.5 * np.pi / 0.6 * np.sin(np.pi / 0.6 * t), \
        0.5 * (np.pi / 0.6) ** 2 * np.cos(np.pi / 0.6 * t)
    d = np.array([0.01, -0.01, 0.005, 0.02, -0.02, 0.03])
    ref = Reference(t, home + np.outer(s, d), np.outer(ds, d), np.outer(dds, d))
    plant = StrutPlant(machine, PlantParameters(faults=faults, encoder_noise_m=1e-7, seed=5,
                                                link_length_errors=link_length_errors))
    return run(machine, ControllerConfig(strategy=strategy, integral_time_s=0.1), plant, 800, reference=ref)


STRUT_CASES = [("genhexkins", "computed_torque", (), ()), ("genhexkins", "cartesian_pid", (), ()),
               ("hexapod8", "decentralized_projected", (), (0.01,) + (0.0,) * 7),
               ("genhexkins", "computed_torque", ("3:encoder_freeze:0.2",), ())]        # a trip


@pytest.mark.parametrize("machine_name, strategy, faults, errors", STRUT_CASES)
def test_a_hexapods_one_call_is_the_two_calls_it_replaces(machine_name, strategy, faults, errors, monkeypatch):
    """StrutDynamics.encoder_state (the readings' forward kinematics and the measured
    state in one kernel) against forward_kinematics_floats, then measured_state."""
    from pkm_kinematics.rigid_body import StrutDynamics
    calls = []
    monkeypatch.setattr(StrutDynamics, "measured_state",
                        lambda self, *a, _f=StrutDynamics.measured_state: calls.append(1) or _f(self, *a))
    fused_core, fused = strut_move(machine_name, strategy, faults, errors)
    assert len(calls) <= 1, len(calls)                 # one call each cycle (measured_state: the start's alone)
    calls.clear()
    monkeypatch.setattr(pose_estimation, "FUSE_ENCODER_STATE", False)
    core, log = strut_move(machine_name, strategy, faults, errors)
    assert len(calls) > 50 and len(log.forces) > 50    # the two calls were taken (until a trip)
    assert (core.stopped, core.stop_reason) == (fused_core.stopped, fused_core.stop_reason)
    assert core.stopped == bool(faults), core.stop_reason
    assert np.array_equal(np.array(log.forces), np.array(fused.forces))
    assert core.estimator.pose == fused_core.estimator.pose


def test_what_a_hexapods_call_refuses_is_named_by_the_interpreted_path():
    from pkm_kinematics.rigid_body import StrutDynamics
    machine = load_machine("genhexkins")
    dynamics = StrutDynamics(machine.model, machine.dynamics)
    home_q = machine.model.inverse_kinematics(machine.model.home)
    pose, state = dynamics.encoder_state(home_q, None, np.zeros(6))
    assert list(pose) == list(machine.model.forward_kinematics_floats(home_q, None)) and state is not None
    for q in (np.array([0.3, -0.1, 0.3, 0.3, 0.3, 0.3]), np.full(6, 50.0)):     # a negative length; out of reach
        assert dynamics.encoder_state(q, None, np.zeros(6)) == (None, None)
        with pytest.raises((KinematicsError, ValueError)):
            machine.model.forward_kinematics_floats(q, None)
