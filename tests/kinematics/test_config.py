"""Machine configuration files: all load; every defect names its field."""

import copy

import numpy as np
import pytest
import yaml

from pkm_kinematics import ConfigError, config_dir, load_machine, load_machine_data, machine_names
from pkm_kinematics.rails import RailMachine
from pkm_kinematics.task_space import PLANAR, POSITION


def raw(name):
    with open(config_dir() / "machines" / f"{name}.yaml") as fh:
        return yaml.safe_load(fh)


def test_all_machines_load():
    assert {"archi", "sliding_star", "mom3", "orthoglide"} <= set(machine_names())
    for name, space, forward in (("archi", PLANAR, "least_squares"), ("sliding_star", PLANAR, "least_squares"),
                                 ("orthoglide", POSITION, "three_spheres")):
        model = load_machine(name).model
        assert isinstance(model, RailMachine) and (model.task_space, model.forward) == (space, forward)
    mom3 = load_machine("mom3")
    assert isinstance(mom3.model, RailMachine) and mom3.metrology is not None
    assert load_machine(config_dir() / "machines" / "archi.yaml").name == "archi"


def test_the_forward_solver_is_chosen_by_the_configuration():
    """ARCHI's drive positions solved by the least squares without its leg pairs'
    closed form (Sliding Star's way) and with it: the same pose."""
    data = copy.deepcopy(raw("archi"))
    data["forward_solver"] = "least_squares"
    model = load_machine_data(data, "archi.yaml").model
    pose = np.array([1.05, -0.38, 0.8])
    q = model.inverse_kinematics(pose)
    assert model.fk.pairs and model.forward_kinematics(q).iterations <= 2       # from the closed form
    np.testing.assert_allclose(model.forward_kinematics(q, guess=pose + 0.01).pose, pose, atol=1e-12)


@pytest.mark.parametrize("mutate,field,message", [
    (lambda d: d["legs"][2].pop("link_length"), "legs[2].link_length", "missing field"),
    (lambda d: d["legs"][1].update(link_length=-1.0), "legs[1].link_length", r"must be in \(0, inf\] m, got -1"),
    (lambda d: d["legs"][0].update(assembly=2), "legs[0].assembly", "must be -1 or \\+1"),
    (lambda d: d["legs"][3].update(joint_limits=[2.0, 1.0]), "legs[3].joint_limits", "min < max"),
    (lambda d: d["legs"][0].update(rail_direction=[0.0, 0.0]), "legs[0].rail_direction", "non-zero"),
    # the drives' names are the messages' joint names: a duplicate was accepted
    (lambda d: d["legs"][3].update(name=d["legs"][1]["name"]), "legs",
     r"leg names must be unique, got \['q1', 'q2', 'q3', 'q2'\]"),
    (lambda d: d["legs"][0].update(platform_point=[0.1, "a"]), r"legs[0].platform_point[1]", "finite number"),
    (lambda d: d.update(kind="hexapod"), "kind", r"must be one of \['planar', 'translational', 'struts', 'parallelograms'\]"),
    (lambda d: d.update(home_pose=[1.0, -3.0, 0.0]), "home_pose", "unreachable"),
    (lambda d: d.update(home_pose=[3.3, -0.4, 0.0]), "home_pose", "outside joint_limits"),
    (lambda d: d.pop("workspace"), "workspace", "missing section"),
    (lambda d: d["workspace"].update(theta_deg=[10, 0]), "workspace.theta_deg", "min < max"),
    (lambda d: d.update(forward_solver="magic"), "forward_solver", r"must be one of \['least_squares', 'three_spheres'\]"),
    (lambda d: d.update(forward_solver="three_spheres"), "forward_solver", "three_spheres solves a translating machine"),
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


def test_an_unchanged_machine_file_is_loaded_once_and_read_only(tmp_path):
    import dataclasses
    archi = load_machine("archi")
    assert load_machine("archi") is archi                     # the same file: the same config
    with pytest.raises(dataclasses.FrozenInstanceError):
        archi.dynamics = None
    path = tmp_path / "archi.yaml"
    text = (config_dir() / "machines" / "archi.yaml").read_text()
    path.write_text(text)
    copy_of = load_machine(path)
    assert copy_of is not archi and load_machine(path) is copy_of
    path.write_text(text.replace("name: archi", "name: archz", 1))     # the same size, maybe the same mtime
    changed = load_machine(path)
    assert changed is not copy_of and changed.name == "archz"
