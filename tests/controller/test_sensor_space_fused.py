"""The sensor-space cycle's second half in one compiled call
(sensor_space.sensor_space_command_kernel) against the same feedback and command in
two (SensorSpaceFeedback.error_from, then laws.cartesian_command_kernel): the same
commands every cycle, bit for bit, the same trips."""

import numpy as np
import pytest

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_trajectory.planner import Limits, Line, plan
import pkm_controller.controller as controller_module
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.reference import Reference

LIMITS = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))


def move(machine_name, faults=(), load=None, **config):
    machine = load_machine(machine_name)
    planar = machine.kind == "planar"
    home = machine.model.home.tolist()
    end = [home[0] + 0.04, home[1] + 0.02, home[2] + (0.1 if planar else 0.0)]
    samples = plan([Line(np.array(home), np.array(end))], LIMITS, translation_axes=2 if planar else 3)
    plant = Plant(machine, PlantParameters(force_limit_n=config.pop("plant_limit_n", 2000.0), faults=faults,
                                           encoder_noise_m=1e-7, seed=3))
    ref = Reference(samples.time_s, samples.position, samples.velocity, samples.acceleration)
    return run(machine, ControllerConfig(strategy="sensor_space", **config), plant,
               int(samples.duration_s * 1000) + 100, reference=ref, sensor=GoughSensorModel(machine.metrology),
               load=load)


CASES = [("archi", {}, ()), ("mom3", {}, ()), ("archi", {"distribution": "pseudo_inverse"}, ()),
         ("mom3", {"force_limit_n": 60.0}, ()),                             # saturating: no integration then
         ("archi", {}, ("1:encoder_slip:0.1:2e-4",)),                     # a trip
         ("mom3", {"following_error_m": 2e-4, "start_tolerance_m": 1e-4}, ())]


@pytest.mark.parametrize("machine_name, config, faults", CASES)
def test_one_call_is_the_two_calls_it_replaces(machine_name, config, faults, monkeypatch):
    fused_core, fused = move(machine_name, faults, **config)
    assert fused_core.fused_struts
    monkeypatch.setattr(controller_module, "FUSE_SENSOR_SPACE", False)
    core, log = move(machine_name, faults, **config)
    assert not core.fused_struts
    assert (core.stopped, core.stop_reason) == (fused_core.stopped, fused_core.stop_reason)
    assert len(log.forces) == len(fused.forces) > 50
    assert np.array_equal(np.array(log.forces), np.array(fused.forces))
    assert np.array_equal(np.array(log.tool), np.array(fused.tool))
    assert core.metrology.estimate == fused_core.metrology.estimate
    assert core.record.measured == fused_core.record.measured and core.record.error == fused_core.record.error
