"""The CANopen master (pkm_drives.canopen_master) over python-can's virtual bus with
four virtual drives on a bench (independent masses): boot (SDO configuration, PDO
mapping, NMT, heartbeats), enabling, the cycle's values against the physics, and each
fault through the bus detected with its cause and drive named, within one cycle."""

import dataclasses
import itertools
import time

import can
import canopen
import pytest

from pkm_common.causes import TripCause
from pkm_drives.canopen_master import CanopenMaster, DriveStartError, check_dictionary, pdo_bytes
from pkm_drives.cia402 import State
from pkm_drives.drive_config import drive_settings
from pkm_drives.virtual_drive import DEFAULT_EDS, MassAxes, VirtualMachine
from pkm_kinematics.config import load_machine
from pkm_kinematics.errors import FieldError

DT_S = 0.002
_channels = itertools.count()


class Rig:
    def __init__(self, node_ids=None, boot_drives=True):
        channel = f"test_canopen_master_{next(_channels)}"
        # on a bench: absolute encoders, no homing (test_homing.py homes)
        self.settings = dataclasses.replace(drive_settings(load_machine("archi"), {"interface": "virtual",
                                                                                   "channel": channel}),
                                            homing_methods=(), homing_order=(), home_positions=())
        self.nets = []
        for _ in range(2):
            net = canopen.Network(can.Bus(interface="virtual", channel=channel))
            net.NOTIFIER_CYCLE = 0.05
            self.nets.append(net.connect())
        self.axes = MassAxes(4, mass_kg=5.0, friction_ns_per_m=20.0, dt_s=DT_S)
        self.machine = VirtualMachine(self.nets[0], self.axes, node_ids or self.settings.node_ids,
                                      self.settings.scaling)
        if boot_drives:
            self.machine.boot()
        self.master = CanopenMaster(self.nets[1], self.settings, DEFAULT_EDS, pdo_timeout_s=0.3)

    def close(self):
        for net in self.nets:
            net.disconnect()
        assert self.machine.errors == [] and all(d.errors == [] for d in self.machine.drives)


@pytest.fixture
def rig():
    r = Rig()
    r.master.boot()
    r.first = r.master.enable()
    yield r
    r.close()


def test_boot_configures_the_drives_and_enable_reaches_operation_enabled(rig):
    drive = rig.machine.drives[0]
    assert drive.node.sdo[0x1017].raw == 100 and drive.node.sdo[0x6060].raw == 10
    assert drive.node.sdo[0x6072].raw == 2000                       # 2000 N of a 1000 N rated drive
    assert [m.trans_type for m in drive.node.tpdo.values() if m.enabled] == [1, 1]
    assert [[v.index for v in m] for m in drive.node.tpdo.values() if m.enabled] == [[0x6041, 0x6064, 0x6077],
                                                                                      [0x606C]]
    assert rig.first.states == [State.OPERATION_ENABLED] * 4
    assert rig.master.syncs <= 5, "2, 3, 4: three controlwords after the first SYNC"


def test_forces_out_positions_in_one_cycle_late(rig):
    """Synchronous RPDOs act at the SYNC after them: the force of cycle k moves the
    axes from SYNC k+1 on; the readings are the axes' own, scaled to 1 count."""
    forces = [10.0, -20.0, 0.0, 500.0]
    r1 = rig.master.cycle(forces)
    assert r1.positions == [0.0] * 4 and r1.forces == [0.0] * 4     # the period before: no force yet
    r2 = rig.master.cycle(forces)
    assert r2.forces == forces
    for _ in range(20):
        r = rig.master.cycle(forces)
    assert rig.master.check(r) == []
    for k in range(4):
        assert abs(r.positions[k] - rig.axes.position[k]) <= 0.5e-6
        assert abs(r.velocities[k] - rig.axes.velocity[k]) <= 0.5e-6
    assert r.positions[3] > r.positions[0] > 0.0 > r.positions[1]


FAULTS = [("over_current", TripCause.DRIVE_FAULT, 0x2310),
          ("following_error", TripCause.DRIVE_FAULT, 0x8611),
          ("encoder", TripCause.DRIVE_FAULT, 0x7305),
          ("silent", TripCause.PDO_MISSED, 0)]


@pytest.mark.parametrize("fault,cause,code", FAULTS)
def test_a_drive_fault_is_found_in_the_cycle_it_happens(rig, fault, cause, code):
    for _ in range(5):
        rig.master.cycle([50.0] * 4)
    rig.machine.drives[2].inject(fault)
    r = rig.master.cycle([50.0] * 4)
    trips = rig.master.check(r)
    assert trips, "found in the first cycle after the fault"
    first = trips[0]
    assert (first.cause, first.drive, first.node_id, first.code) == (cause, 2, 3, code), first.text()
    assert "drive q3 (node 3)" in first.text()
    failed = rig.master.quick_stop()
    assert failed == [] if fault != "silent" else (len(failed) == 1 and failed[0].startswith("drive q3 (node 3)")), \
        failed
    moved = list(rig.axes.position)
    r = rig.master.cycle([50.0] * 4)
    r = rig.master.cycle([50.0] * 4)
    # every drive answering is out of operation enabled, its brake holding; nothing moved
    assert all(st is not State.OPERATION_ENABLED for k, st in enumerate(r.states) if k not in r.missed)
    assert rig.axes.position == moved


def test_heartbeat_lost_is_found_after_its_consumer_time(rig):
    rig.machine.drives[1].inject("heartbeat_lost")
    start = time.monotonic()
    trips = []
    while not trips and time.monotonic() - start < 5.0:
        r = rig.master.cycle([0.0] * 4)
        trips = rig.master.check(r)
        time.sleep(0.01)
    elapsed = time.monotonic() - start
    assert trips and trips[0].cause is TripCause.HEARTBEAT_LOST and trips[0].drive == 1, trips
    # 3 periods of 100 ms after the last heartbeat: between 0.2 and 0.3 s after the fault, plus a check's delay
    assert 0.2 <= elapsed <= 1.0, elapsed


def test_a_drive_left_operation_enabled_is_named():
    rig = Rig()
    try:
        rig.master.boot()
        rig.master.enable()
        rig.machine.drives[0].node.sdo[0x6040].raw = 0x02          # its own quick stop (a local input)
        trips = []
        for _ in range(3):
            trips = rig.master.check(rig.master.cycle([0.0] * 4))
            if trips:
                break
        assert trips[0].cause is TripCause.DRIVE_DISABLED and trips[0].drive == 0, trips
        assert "quick stop active" in trips[0].text() or "switch on disabled" in trips[0].text()
    finally:
        rig.close()


def test_a_missing_drive_is_named_at_boot():
    rig = Rig(node_ids=(1, 2, 3, 9))          # the fourth drive answers to another node ID
    try:
        with pytest.raises(DriveStartError, match=r"drive q4 \(node 4\) does not answer"):
            rig.master.boot()
    finally:
        rig.close()


def test_an_eds_without_a_mapped_object_is_refused(tmp_path):
    text = DEFAULT_EDS.read_text()
    start = text.index("[6077]")
    end = text.index("\n\n", start)
    eds = tmp_path / "no_torque_actual.eds"
    eds.write_text(text[:start] + text[end + 2:])
    od = canopen.import_od(str(eds), 1)
    with pytest.raises(FieldError) as info:
        check_dictionary(od, eds.name)
    assert info.value.name == "drives.eds" and "0x6077 torque actual value" in str(info.value)
    assert pdo_bytes(canopen.import_od(str(DEFAULT_EDS), 1)) == ([4], [8, 4])
