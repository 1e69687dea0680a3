"""Machine configuration files: all load; every defect names its field."""

import copy

import pytest
import yaml

from pkm_kinematics import ConfigError, config_dir, load_machine, load_machine_data, machine_names
from pkm_kinematics.planar import PlanarMachine
from pkm_kinematics.translational import TranslationalMachine


def raw(name):
    with open(config_dir() / "machines" / f"{name}.yaml") as fh:
        return yaml.safe_load(fh)


def test_all_machines_load():
    assert {"archi", "sliding_star", "mom3", "orthoglide"} <= set(machine_names())
    assert isinstance(load_machine("archi").model, PlanarMachine)
    assert isinstance(load_machine("sliding_star").model, PlanarMachine)
    assert isinstance(load_machine("orthoglide").model, TranslationalMachine)
    mom3 = load_machine("mom3")
    assert isinstance(mom3.model, TranslationalMachine) and mom3.metrology is not None
    assert load_machine(config_dir() / "machines" / "archi.yaml").name == "archi"


@pytest.mark.parametrize("mutate,field,message", [
    (lambda d: d["legs"][2].pop("link_length"), "legs[2].link_length", "missing field"),
    (lambda d: d["legs"][1].update(link_length=-1.0), "legs[1].link_length", r"must be in \(0, inf\] m, got -1"),
    (lambda d: d["legs"][0].update(assembly=2), "legs[0].assembly", "must be -1 or \\+1"),
    (lambda d: d["legs"][3].update(joint_limits=[2.0, 1.0]), "legs[3].joint_limits", "min < max"),
    (lambda d: d["legs"][0].update(rail_direction=[0.0, 0.0]), "legs[0].rail_direction", "non-zero"),
    (lambda d: d["legs"][0].update(platform_point=[0.1, "a"]), r"legs[0].platform_point[1]", "finite number"),
    (lambda d: d.update(kind="hexapod"), "kind", r"must be one of \['planar', 'translational', 'struts', 'parallelograms'\]"),
    (lambda d: d.update(home_pose=[1.0, -3.0, 0.0]), "home_pose", "unreachable"),
    (lambda d: d.update(home_pose=[3.3, -0.4, 0.0]), "home_pose", "outside joint_limits"),
    (lambda d: d.pop("workspace"), "workspace", "missing section"),
    (lambda d: d["workspace"].update(theta_deg=[10, 0]), "workspace.theta_deg", "min < max"),
])
def test_defects_name_their_field(mutate, field, message):
    data = copy.deepcopy(raw("archi"))
    mutate(data)
    with pytest.raises(ConfigError, match=message) as info:
        load_machine_data(data, "archi.yaml")
    assert f"archi.yaml: {field}" in str(info.value)


def test_metrology_defects_name_their_field():
    data = copy.deepcopy(raw("mom3"))
    data["metrology"]["encoder_resolution"] = 0.0
    with pytest.raises(ConfigError, match=r"metrology.encoder_resolution: must be in \(0, 0.001\] m"):
        load_machine_data(data, "mom3.yaml")
    data = copy.deepcopy(raw("mom3"))
    data["metrology"]["home_position"] = [0.0, 0.0, -0.5]
    with pytest.raises(ConfigError, match="metrology.home_position: z must be > 0"):
        load_machine_data(data, "mom3.yaml")
    data = copy.deepcopy(raw("mom3"))
    data["metrology"]["home_position"] = [0.0, 0.0, 0.3]
    with pytest.raises(ConfigError, match="metrology.home_position: strut lengths at home .* leave strut_limits"):
        load_machine_data(data, "mom3.yaml")
    data = copy.deepcopy(raw("mom3"))
    data["metrology"]["geometry"]["alpha_base_deg"] = 0
    with pytest.raises(ConfigError, match=r"metrology.geometry.alpha_base_deg: must be in \(0, 120\]"):
        load_machine_data(data, "mom3.yaml")
    data = copy.deepcopy(raw("mom3"))
    data["home_position"] = [0.0, 0.0, 1.3]
    with pytest.raises(ConfigError, match="mom3.yaml: home_position: leg q1: position .* outside joint_limits"):
        load_machine_data(data, "mom3.yaml")


def test_unknown_machine_lists_the_known_ones():
    with pytest.raises(ConfigError, match="unknown machine 'hexa'.*archi"):
        load_machine("hexa")


def test_invalid_yaml(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match="bad.yaml: invalid YAML"):
        load_machine(bad)
