"""Homing CiA 402 drives over CANopen: the master (pkm_drives.canopen_master.home)
homes four virtual drives on a bench, each with its method, group after group, in
homing mode (0x6098, 0x607C, 0x6099, controlword bit 4, statusword bits 10, 12, 13);
motion before homing is refused; a homing that fails names its drive."""

import copy
import itertools

import can
import canopen
import pytest

from pkm_drives.canopen_master import CanopenMaster, DriveStartError
from pkm_drives.cia402 import HomingStatus, State, homing_status
from pkm_drives.drive_config import drive_settings
from pkm_drives.virtual_drive import DEFAULT_EDS, HomingSetup, MassAxes, VirtualMachine
from pkm_kinematics.config import load_machine, load_machine_data
from pkm_kinematics.errors import FieldError

DT = 0.002
HOME = [0.1, 0.2, 0.3, 0.4]
OFFSETS = [0.01, -0.02, 0.03, 0.05]
_channels = itertools.count()


def rig(methods, start, order=((0, 1, 2), (3,))):
    channel = f"test_canopen_homing_{next(_channels)}"
    data = copy.deepcopy(load_machine("archi").data)
    data["drives"]["homing"] = {"method": list(methods), "order": [list(g) for g in order], "home_position": HOME}
    settings = drive_settings(load_machine_data(data, "archi.yaml"), {"interface": "virtual", "channel": channel})
    nets = []
    for _ in range(2):
        net = canopen.Network(can.Bus(interface="virtual", channel=channel))
        net.NOTIFIER_CYCLE = 0.05
        nets.append(net.connect())
    axes = MassAxes(4, mass_kg=5.0, friction_ns_per_m=20.0, dt_s=DT, start=start, offsets=OFFSETS)
    machine = VirtualMachine(nets[0], axes, settings.node_ids, settings.scaling, homing=HomingSetup(5.0, dt_s=DT))
    machine.boot()
    master = CanopenMaster(nets[1], settings, DEFAULT_EDS)
    master.boot()
    return nets, axes, machine, master


def close(nets, machine):
    for net in nets:
        net.disconnect()
    assert machine.errors == [] and all(d.errors == [] for d in machine.drives)


def test_four_methods_home_each_drive_at_its_mark_group_after_group():
    nets, axes, machine, master = rig([19, 34, 33, 35], start=[0.098, 0.1971, 0.3022, 0.4123])
    try:
        with pytest.raises(FieldError, match="not homed: motion commands are refused"):
            master.cycle([10.0] * 4)
        readings = master.home()
        # the first group's drives homed together, the fourth free meanwhile, then it
        first_done = next(i for i, r in enumerate(readings)
                          if all(homing_status(r.statuswords[k]) is HomingStatus.COMPLETED for k in (0, 1, 2)))
        assert homing_status(readings[first_done].statuswords[3]) is not HomingStatus.COMPLETED
        assert homing_status(readings[-2].statuswords[3]) is HomingStatus.COMPLETED
        assert readings[-1].states == [State.SWITCHED_ON] * 4                  # brakes closed after it
        reading = master.enable()
        # the marks: a switch at 0.1, the index above 0.1971 (0.2), the index below 0.3022 (0.3); the
        # fourth homed where it was (35: current position is 0.4)
        for k in range(3):
            assert reading.positions[k] == pytest.approx(axes.position[k], abs=1.5e-6), k
            assert abs(axes.position[k] - HOME[k]) <= 2e-6, (k, axes.position[k])
        assert reading.positions[3] == pytest.approx(0.4, abs=2e-6) and axes.position[3] == pytest.approx(
            0.4123, abs=2e-6)
        master.cycle([0.0] * 4)                                               # homed: commands go through
    finally:
        close(nets, machine)


def test_a_homing_that_finds_no_mark_names_its_drive():
    nets, axes, machine, master = rig([19, 19, 19, 35], start=[0.098, 0.26, 0.298, 0.4])   # q2 60 mm off
    try:
        with pytest.raises(DriveStartError, match=r"homing: drive q2 \(node 2\) method 19: error stopped"):
            master.home()
        assert not master.homed
    finally:
        close(nets, machine)
