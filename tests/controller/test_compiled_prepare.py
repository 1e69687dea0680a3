"""The first half of a usual cycle in one compiled call (compiled_prepare.prepare_kernel)
against the interpreted ControllerCore.prepare it stands for: the same commands every
cycle, bit for bit, the same true motion and the same trips, over the strategies and
machines that have it, with faults that leave the usual cycle (a slip, a freeze, a
drive that stops producing force, a brake). The compiled path must be the one taken:
its cycles are counted."""

import numpy as np
import pytest

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_trajectory.planner import Limits, Line, plan
import pkm_controller.compiled_prepare as compiled_module
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.reference import Reference

LIMITS = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))


def move(machine_name, strategy, faults=(), counts=None, **config):
    machine = load_machine(machine_name)
    planar = machine.kind == "planar"
    home = machine.model.home.tolist()
    end = [home[0] + 0.04, home[1] + 0.02, home[2] + (0.1 if planar else 0.0)]
    samples = plan([Line(np.array(home), np.array(end))], LIMITS, translation_axes=2 if planar else 3)
    plant = Plant(machine, PlantParameters(force_limit_n=2000.0, faults=faults, encoder_noise_m=1e-7, seed=3))
    ref = Reference(samples.time_s, samples.position, samples.velocity, samples.acceleration)
    core = ControllerCore(machine, ControllerConfig(strategy=strategy, **config))
    if counts is not None and core.compiled is not None:
        prepare = core.compiled.prepare

        def counted(*args):
            cycle = prepare(*args)
            counts[cycle is not None] += 1
            return cycle
        core.compiled.prepare = counted
    return run(machine, core, plant, int(samples.duration_s * 1000) + 100, reference=ref,
               sensor=GoughSensorModel(machine.metrology), load=lambda t: (40.0, -30.0, 0.0) if t > 0.05 else
               (0.0, 0.0, 0.0))


CASES = [("archi", "sensor_space", {}, ()), ("mom3", "sensor_space", {}, ()),
         ("archi", "computed_torque", {}, ()), ("mom3", "measured_space", {}, ()),
         ("archi", "joint_pid", {"distribution": "pseudo_inverse"}, ()),
         ("archi", "sensor_space", {}, ("1:encoder_slip:0.1:2e-4",)),       # a slip: judged by the Gough
         ("mom3", "cartesian_pid", {}, ("1:encoder_freeze:0.1",)),            # a freeze: no Gough
         ("archi", "cartesian_pid", {"continue_on_drive_failure": True}, ("2:no_force:0.1",)),   # dropped
         ("mom3", "sensor_space", {}, ("0:locked:0.1",))]                      # locked: a drive's trip


@pytest.mark.parametrize("machine_name, strategy, config, faults", CASES)
def test_the_compiled_prepare_is_the_interpreted_one(machine_name, strategy, config, faults, monkeypatch):
    counts = [0, 0]                     # cycles the compiled prepare left to the interpreted one, took
    fast_core, fast = move(machine_name, strategy, faults, counts, **config)
    assert fast_core.compiled is not None
    monkeypatch.setattr(compiled_module, "COMPILE_PREPARE", False)
    core, log = move(machine_name, strategy, faults, **config)
    assert core.compiled is None
    assert (core.stopped, core.stop_reason) == (fast_core.stopped, fast_core.stop_reason)
    assert core.supervisor.faults == fast_core.supervisor.faults
    assert len(log.forces) == len(fast.forces) > 50
    assert np.array_equal(np.array(log.forces), np.array(fast.forces))
    assert np.array_equal(np.array(log.tool), np.array(fast.tool))
    assert core.record.measured == fast_core.record.measured and core.record.error == fast_core.record.error
    # the usual cycles compiled: every cycle answered before a fault (at 0.1 s, cycle 100) but the
    # first few; a machine on fewer drives is not a usual cycle's (interpreted)
    usual = min(fast_core.cycles, 100) if faults else fast_core.cycles
    assert usual - 5 <= counts[1] <= fast_core.cycles, (counts, fast_core.cycles)
    if faults:
        assert counts[0] >= 1, counts


def test_machines_and_configurations_without_it_are_interpreted():
    assert ControllerCore(load_machine("archi"), ControllerConfig(forward_kinematics="integrated")).compiled is None
    assert ControllerCore(load_machine("archi"), ControllerConfig(actuation_delay_cycles=1)).compiled is None
    assert ControllerCore(load_machine("hexapod8"), ControllerConfig()).compiled is None     # 6 task axes
    assert ControllerCore(load_machine("archi"), ControllerConfig()).compiled is not None
