"""A whole closed-loop run over virtual CANopen drives without ROS: the controller core
(closed_loop.run) steps CanopenHardware, whose master talks over python-can's virtual
bus to four virtual CiA 402 drives moving the simulated ARCHI; tracked as well as
the same run on the simulated plant directly (within 10 %), with the drives' force
quantisation (1 N) and their synchronous RPDOs' cycle of delay."""

import dataclasses
import itertools

import can
import canopen
import numpy as np
import pytest

from pkm_controller.closed_loop import run as core_loop
from pkm_controller.config import ControllerConfig
from pkm_controller.reference import Reference
from pkm_drives.canopen_master import CanopenMaster
from pkm_drives.drive_config import drive_settings
from pkm_drives.hardware import CanopenHardware, PlantAxes
from pkm_drives.virtual_drive import DEFAULT_EDS, VirtualMachine
from pkm_kinematics import load_machine
from pkm_sim_hw.plant import Plant, PlantParameters

ARCHI = load_machine("archi")
DT_S, STEPS = 0.002, 600
_channels = itertools.count()


def reference() -> Reference:
    """20 mm in x, 10 mm in y and 0.1 rad in 0.96 s, rest to rest."""
    home = ARCHI.model.home.tolist()
    t = np.linspace(0.0, 0.8 * STEPS * DT_S, 200)
    s = 0.5 - 0.5 * np.cos(np.pi * t / t[-1])
    pos = np.array([[home[0] + 0.02 * v, home[1] + 0.01 * v, home[2] + 0.1 * v] for v in s])
    return Reference(t, pos, np.gradient(pos, t, axis=0))


class WithTruth:
    """The hardware, its outputs completed with the virtual plant's true pose (a real
    machine has none; the test measures the tracking with it)."""

    def __init__(self, hardware, plant):
        self.hardware, self.plant = hardware, plant

    def _true(self, out):
        t = self.plant.output()
        return dataclasses.replace(out, tool_pose=t.tool_pose, rigid_pose=t.rigid_pose,
                                   internal_force_norm=t.internal_force_norm)

    def output(self):
        return self._true(self.hardware.output())

    def step(self, forces):
        return self._true(self.hardware.step(forces))


def errors(log) -> tuple[float, float]:
    e = log.tool_error(True)
    return float(e.max()), float(np.sqrt((e ** 2).mean()))


@pytest.mark.parametrize("rpdo", ["synchronous", "on_arrival"])
def test_archi_over_virtual_canopen_drives_tracks_as_on_the_simulated_plant(rpdo):
    config = ControllerConfig(strategy="computed_torque", distribution="inf_norm", dt_s=DT_S)
    _, direct = core_loop(ARCHI, config, Plant(ARCHI, PlantParameters(dt_s=DT_S)), STEPS, reference=reference())

    channel = f"test_canopen_run_{next(_channels)}"
    machine = dataclasses.replace(ARCHI, data={**ARCHI.data, "drives": {**ARCHI.data["drives"], "rpdo": rpdo}})
    settings = dataclasses.replace(drive_settings(machine, {"interface": "virtual", "channel": channel}),
                                   homing_methods=(), homing_order=(), home_positions=())   # absolute encoders
    nets = []
    for _ in range(2):
        net = canopen.Network(can.Bus(interface="virtual", channel=channel))
        net.NOTIFIER_CYCLE = 0.05
        nets.append(net.connect())
    try:
        plant = Plant(ARCHI, PlantParameters(dt_s=DT_S))
        virtual = VirtualMachine(nets[0], PlantAxes(plant), settings.node_ids, settings.scaling)
        virtual.boot()
        hardware = CanopenHardware(CanopenMaster(nets[1], settings, DEFAULT_EDS), settings, DT_S)
        hardware.start()
        core, log = core_loop(ARCHI, config, WithTruth(hardware, plant), STEPS, reference=reference())
    finally:
        for net in nets:
            net.disconnect()
    assert virtual.errors == [] and not hardware.stopped and not core.stopped, (hardware.stop_reason,
                                                                                 core.stop_reason)
    assert plant.k == hardware.k == virtual.steps == STEPS       # one SYNC, one step, on both sides
    (max_direct, rms_direct), (max_bus, rms_bus) = errors(direct), errors(log)
    figures = f"max {max_bus * 1e6:.2f} um vs {max_direct * 1e6:.2f} um, rms {rms_bus * 1e6:.2f} vs " \
              f"{rms_direct * 1e6:.2f} um"
    assert max_bus <= 1.1 * max_direct and rms_bus <= 1.1 * rms_direct, figures
    assert max_direct > 1e-6, "the motion asks for some tracking"
    # the commands reach the plant as the drives' per-mille: within half a unit (0.5 N)
    forces, applied = np.array(log.forces), np.array(log.applied)
    lag = 1 if rpdo == "synchronous" else 0
    quantised = np.abs(applied[1 + lag:] - np.clip(forces[:len(forces) - 1 - lag], -2000, 2000))
    assert quantised.max() <= 0.5 + 1e-9, quantised.max()
