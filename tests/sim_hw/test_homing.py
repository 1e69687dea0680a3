"""Homing incremental encoders (pkm_sim_hw.homing, drives.HomingMotion): each CiA 402
method the simulated drives run finds its mark where the plant says it is, the drive's
position is then the machine's to the encoder's count, and a redundant machine homed
group by group stays assembled and ends at its home pose."""

import copy

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.config import load_machine_data
from pkm_kinematics.errors import ConfigError
from pkm_sim_hw.drives import HomingMotion
from pkm_sim_hw.homing import home, homing_plan
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_sim_hw.strut_plant import StrutPlant

DT = 0.002


def bench(method, start, home_position=0.5, offset=0.0123, gravity=-50.0, pitch=0.005):
    """One 10 kg axis with friction and a constant load, its encoder counting from
    ``offset``; the motion stepped until it ends. (status, latched true, true at the end,
    reported at the end)."""
    motion = HomingMotion(method, home_position, 0.005, 10.0, DT, pitch=pitch)
    x, v = start, 0.0
    for _ in range(8000):                                      # 16 s: over max_travel at 5 mm/s
        f = motion.step(x, x + offset, v)
        v += (f + gravity - 30.0 * v) / 10.0 * DT
        x += v * DT
        if motion.status in ("completed", "error"):
            break
    latched = None if motion.latched is None else motion.latched - offset
    return motion.status, latched, x, x + offset + motion.shift


@pytest.mark.parametrize("method,start,mark", [(19, 0.498, 0.5), (19, 0.5021, 0.5), (21, 0.4987, 0.5),
                                               (34, 0.4981, 0.5), (34, 0.5031, 0.505), (33, 0.5019, 0.5)])
def test_each_method_latches_its_mark_and_the_position_is_the_machines(method, start, mark):
    status, latched, true, reported = bench(method, start)
    assert status == "completed"
    assert latched == pytest.approx(mark, abs=1e-9)           # the capture at the crossing, interpolated
    # the drive's position is home_position at the mark: the machine's, when it started within its pitch
    assert reported - true == pytest.approx(0.5 - mark, abs=1e-9)
    assert abs(true - mark) <= 2e-6                           # back at the mark, at rest


def test_current_position_and_a_mark_never_found():
    status, latched, true, reported = bench(35, 0.4321)
    assert status == "completed" and reported == pytest.approx(0.5, abs=2e-6)   # "here" is home
    assert bench(19, 0.44)[0] == "error"                        # 60 mm from the switch: over max_travel
    with pytest.raises(ValueError, match="not simulated"):
        HomingMotion(17, 0.5, 0.005, 10.0, DT)


def test_archi_homes_three_switches_then_its_redundant_drive_and_ends_at_home():
    archi = load_machine("archi")
    offsets = (0.0123, -0.0311, 0.0207, 0.0415)
    plant = Plant(archi, PlantParameters(dt_s=DT, encoder_offsets_m=offsets), initial_pose=[1.0015, -0.4008, 0.7858])
    assert not plant.homed
    record = home(plant, homing_plan(archi), mass_kg=12.25)
    assert plant.homed and record.status == ["completed"] * 4
    np.testing.assert_allclose(record.shifts[:3], [-o for o in offsets[:3]], atol=1e-12)   # the switches: exact
    assert abs(record.shifts[3] + offsets[3]) < 2e-6             # the fourth, where the three put it
    np.testing.assert_allclose(plant.x, archi.model.home, atol=1e-5)
    reading = np.array(plant.output().encoder_positions)
    np.testing.assert_allclose(reading, archi.model.inverse_kinematics(plant.x), atol=1.5e-6)
    assert plant.k == 0 and plant.t == 0.0                       # the run starts homed, at time 0


def test_after_homing_the_compiled_step_reads_the_encoders_with_their_new_offsets():
    """Homing gives the encoders new offsets: the compiled step (rail_step) reads with
    them as the Python path does (it read with the old ones: 12-41 m/s velocities)."""
    archi = load_machine("archi")
    params = PlantParameters(dt_s=DT, encoder_offsets_m=(0.0123, -0.0311, 0.0207, 0.0415))
    plants = [Plant(archi, params, initial_pose=[1.0015, -0.4008, 0.7858]) for _ in range(2)]
    plants[1].compiled_step = False
    for plant in plants:
        home(plant, homing_plan(archi), mass_kg=12.25)
    hold = [0.0, 0.0, 0.0, 0.0]
    for k in range(20):
        a, b = plants[0].step(hold), plants[1].step(hold)
        assert (a, plants[0].x) == (b, plants[1].x), k
    assert np.abs(a.encoder_velocities).max() < 1.0, a           # falling unpowered, not 12-41 m/s
    np.testing.assert_allclose(a.encoder_positions, archi.model.inverse_kinematics(plants[0].x), atol=1.5e-6)


def test_a_hexapod_homes_its_six_struts_together():
    hexapod = load_machine("genhexkins")
    data = copy.deepcopy(hexapod.data)
    data["drives"]["homing"] = {"method": 19, "home_position": "home_pose"}
    machine = load_machine_data(data, "genhexkins.yaml")
    offsets = tuple(0.01 * (k - 2.5) for k in range(6))
    start = list(machine.model.home)
    start[2] += 0.002                                            # 2 mm above home
    plant = StrutPlant(machine, PlantParameters(dt_s=DT, encoder_offsets_m=offsets), initial_pose=start)
    record = home(plant, homing_plan(machine), mass_kg=2.0 + 20.0 / 6)
    assert record.status == ["completed"] * 6
    np.testing.assert_allclose(plant.x[:3], machine.model.home[:3], atol=2e-5)


@pytest.mark.parametrize("homing,field", [({"method": 17}, "drives.homing.method"),
                                          ({"method": 19, "order": [[0, 1], [2]]}, "drives.homing.order"),
                                          ({"method": 19, "home_position": [0.1, 0.2]}, "drives.homing.home_position"),
                                          ({"method": 19}, "drives.homing.home_position")])
def test_a_bad_homing_section_is_refused_naming_the_field(homing, field):
    data = copy.deepcopy(load_machine("archi").data)
    data["drives"]["homing"] = homing
    with pytest.raises(ConfigError) as info:
        homing_plan(load_machine_data(data, "archi.yaml"))
    assert info.value.name == field, str(info.value)
