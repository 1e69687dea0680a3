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
