"""The machine file's ``drives`` section (pkm_drives.drive_config): read, scaled, and
every bad value refused naming its field."""

import copy

import pytest

from pkm_drives.drive_config import AxisScaling, drive_settings
from pkm_kinematics.config import load_machine, load_machine_data
from pkm_kinematics.errors import ConfigError


@pytest.fixture(scope="module")
def archi():
    return load_machine("archi")


def with_drives(machine, **changes):
    data = copy.deepcopy(machine.data)
    data["drives"].update(changes)
    return load_machine_data(data, "archi.yaml")


def test_archi_drives(archi):
    s = drive_settings(archi)
    assert s.node_ids == (1, 2, 3, 4) and s.names == ("q1", "q2", "q3", "q4")
    assert s.bus.interface == "socketcan" and s.bus.channel == "can0" and s.bus.bitrate == 1_000_000
    assert s.heartbeat_s == 0.1
    assert drive_settings(archi, {"interface": "virtual", "channel": "x"}).bus.interface == "virtual"


def test_scaling_round_trips_within_one_unit():
    sc = AxisScaling(counts_per_unit=1e6, rated_force=1000.0, max_force=2000.0)
    assert sc.max_per_mille == 2000
    for f in (-2000.0, -1.4, 0.0, 0.6, 123.456, 1999.0):
        assert abs(sc.force_from_drive(sc.force_to_drive(f)) - f) <= 0.5
    assert sc.force_to_drive(5000.0) == 2000 and sc.force_to_drive(-1e9) == -2000
    assert sc.force_to_drive(float("nan")) == 0
    for q in (-1.5, 0.0, 1.234567, 3.5):
        assert abs(sc.position_from_drive(sc.position_to_drive(q)) - q) <= 0.5e-6


@pytest.mark.parametrize("changes,field", [
    ({"node_ids": [1, 2, 2, 4]}, "drives.node_ids[2]"),
    ({"node_ids": [1, 2, 3, 128]}, "drives.node_ids[3]"),
    ({"node_ids": [1, 2, 3]}, "drives.node_ids"),
    ({"counts_per_unit": 0.0}, "drives.counts_per_unit"),
    ({"rated_force": [1000.0, 0.0, 1000.0, 1000.0]}, "drives.rated_force[1]"),
    ({"max_force": 40000.0}, "drives.max_force"),
    ({"homing": {"method": 99}}, "drives.homing.method"),
    ({"homing": {"method": [35, 35, 36, 35]}}, "drives.homing.method[2]"),
    ({"homing": {"method": 35, "order": [[0, 1], [1, 2, 3]]}}, "drives.homing.order"),
    ({"bus": {"bitrate": 2_000_000}}, "drives.bus.bitrate"),
    ({"heartbeat_ms": 0}, "drives.heartbeat_ms"),
])
def test_bad_values_are_refused_naming_the_field(archi, changes, field):
    with pytest.raises(ConfigError) as info:
        drive_settings(with_drives(archi, **changes))
    assert info.value.name == field, str(info.value)


def test_machine_without_drives_section_is_refused():
    with pytest.raises(ConfigError, match="no drives section"):
        drive_settings(load_machine("sliding_star"))
