"""Scenario files -> node parameters (pure; no ROS graph)."""

import math
import re
from pathlib import Path

import pytest
import yaml

from pkm_bringup.scenario import ScenarioError, load_scenario, node_parameters, params_file_text
from pkm_kinematics.config import config_dir
from pkm_sim_hw.loads import ramp_steps

SCENARIOS = sorted((config_dir() / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_shipped_scenarios_load(path, tmp_path):
    s = load_scenario(path)
    params = node_parameters(s, tmp_path)
    assert s.duration_s > 0
    assert params[s.machine_node]["machine"] == s.machine
    assert params["controller"]["machine"] == s.controller_machine       # the machine, or the scenario's model
    assert params["controller"]["state_source"] == f"{s.namespace}/{s.machine_node}"
    for name, values in params.items():   # every file is a valid --params-file
        data = yaml.safe_load(params_file_text(values))
        assert data["/**"]["ros__parameters"] == values, name


def test_each_loop_input_is_wired_to_its_one_source(tmp_path):
    """Who may publish what the plant and the controller act on: the run's own nodes."""
    p = node_parameters(load_scenario("archi_demo", {"namespace": "/cell2"}), tmp_path)
    assert p["sim_hw"]["command_source"] == "/cell2/controller"
    assert (p["controller"]["state_source"], p["controller"]["metrology_source"]) == \
        ("/cell2/sim_hw", "/cell2/gough_sensor")
    no_metrology = node_parameters(load_scenario("archi_demo", {"metrology": False,
                                                                "controller": {"strategy": "computed_torque"}}),
                                   tmp_path)["controller"]
    assert no_metrology["state_source"] == "/pkm/sim_hw" and "metrology_source" not in no_metrology


def test_default_scenario_is_the_archi_demo():
    s = load_scenario("archi_demo")
    assert (s.machine, s.strategy, s.controller["distribution"], s.metrology, s.record) == \
        ("archi", "sensor_space", "inf_norm", True, True)
    assert s.load, "the demo runs under a cutting load"


def test_duration_is_the_program_plus_settling():
    s = load_scenario("mom3_square")
    # mom3_square.nc plans to 1.726 s (tests/trajectory); + settle_s
    assert s.duration_s == pytest.approx(1.726 + s.settle_s, abs=2e-3)


def test_parameters_are_typed_for_ros(tmp_path):
    s = load_scenario("mom3_square", {"dt_s": 0.001, "controller": {"strategy": "sensor_space", "bandwidth_hz": 15,
                                                                    "drive_mismatch_cycles": 7},
                                      "load": [{"t_s": 0, "wrench": [1, 2, 3]}]})
    p = node_parameters(s, tmp_path)
    assert isinstance(p["controller"]["bandwidth_hz"], float)        # ROS double, not integer
    assert isinstance(p["controller"]["drive_mismatch_cycles"], int)
    assert p["sim_hw"]["load_profile"] == [0.0, 0.0, 1.0, 2.0, 3.0]         # t_s, ramp_s, the wrench
    assert "link_length_errors" not in p["sim_hw"]          # ARCHI-sized default dropped for MoM3
    # the loop starts at pkm-run's start, once the recorder is ready, and with its trajectory
    assert p["controller"]["wait_for_trajectory"] is True and p["controller"]["wait_for_start"] is True
    assert set(p) == {"sim_hw", "controller", "gough_sensor", "trajectory", "recorder"}
    assert p["recorder"]["output"] == str(tmp_path / "bag")


@pytest.mark.parametrize("overrides, field", [
    ({"machine": "nope"}, "machine"),
    ({"mode": "fast"}, "mode"),
    ({"dt_s": 0.0}, "dt_s"),
    ({"color": 1}, "color"),
    ({"controller": {"strategy": "magic"}}, "controller.strategy"),
    ({"metrology": False}, "metrology"),                 # sensor_space needs the Gough
    ({"load": [{"t_s": 1.0, "wrench": [1, 2]}]}, "load[0]"),
    ({"load": [{"t_s": 1.0, "wrench": [1, 2, 3]}, {"t_s": 0.5, "wrench": [1, 2, 3]}]}, "load"),
    ({"program": "missing.nc"}, "program"),
    ({"namespace": "pkm"}, "namespace"),
    ({"namespace": "/pkm bad"}, "namespace"),
    ({"name": "../evil"}, "name"),
    ({"record": "false"}, "record"),                     # a string is not a boolean
    ({"controller": {"strategy": "sensor_space", "kp_typo": 3.0}}, "controller.kp_typo"),
    ({"plant": {"link_length_errors": [0.0, "x", 0.0]}}, "plant.link_length_errors"),
    ({"load": [{"t_s": 0.1, "wrench": [1, 2, 3], "ramp": 0.1}]}, "load[0].ramp"),
    ({"load": [{"t_s": 0.1, "wrench": [1, 2, 3], "ramp_s": 0.2}, {"t_s": 0.2, "wrench": [0, 0, 0]}]}, "load[1]"),
    ({"frame_load": [{"t_s": 1.0, "wrench": [1, 2]}]}, "frame_load[0]"),
    ({"frame_load": [{"t_s": 0.5, "wrench": [0.0, 1e6, 0.0]}], "plant": {"frame_compliance": [1e-8] * 3}},
     "frame_load: fy must be in"),
    ({"frame_load": [{"t_s": 0.5, "wrench": [0.0, 10.0, 0.0]}]}, "frame_load: needs plant.frame_compliance"),
    ({"plant": {"frame_compliance": [1e-7, -1.0, 0.0]}}, "plant.frame_compliance"),
    ({"trajectory": {"scale": 50.0}}, "program"),       # the program leaves the workspace: refused up front
    ({"recorder": {"compression": "bz2"}}, "recorder.compression"),
    ({"recorder": {"output": "elsewhere"}}, "recorder.output"),        # pkm-run's wiring, not the scenario's
])
def test_bad_scenarios_name_the_key(overrides, field):
    with pytest.raises(ScenarioError, match="^" + re.escape(field)):
        load_scenario("mom3_square", overrides)


def test_metrology_needs_a_machine_with_one(tmp_path):
    path = Path(tmp_path) / "s.yaml"
    path.write_text("machine: sliding_star\nmetrology: true\nduration_s: 1\n")
    with pytest.raises(ScenarioError, match="^metrology: machine sliding_star has no metrology"):
        load_scenario(path)


def test_a_machine_the_graph_does_not_run_yet_is_refused_by_name():
    with pytest.raises(ScenarioError, match="^machine: mom3_imperfect is a parallelograms machine; the graph "
                                            "\\(plant, controller, planner\\) runs planar, translational, struts"):
        load_scenario("mom3_square", {"machine": "mom3_imperfect"})


def test_a_ramp_may_end_exactly_where_the_next_entry_starts():
    s = load_scenario("mom3_square", {"dt_s": 0.001, "load": [
        {"t_s": 0.1, "wrench": [10.0, 0.0, 0.0], "ramp_s": 0.2}, {"t_s": 0.3, "wrench": [0.0, 0.0, 0.0]}]})
    steps = ramp_steps(s.load, s.dt_s)            # as the plant expands them (pkm_sim_hw.loads)
    assert len(steps) == 201 and steps[199][1][0] == pytest.approx(10.0) and steps[-1] == (0.3, (0.0, 0.0, 0.0))


def test_a_scenario_without_program_waits_for_the_start_signal(tmp_path):
    s = load_scenario("archi_fig12")
    p = node_parameters(s, tmp_path)
    assert s.program is None and "trajectory" not in p
    assert p["controller"]["wait_for_start"] is True         # the loop starts after the recorder is ready
    assert p["controller"]["wait_for_trajectory"] is False


def test_the_recorder_section_sets_recorder_parameters_and_pkm_run_the_wiring(tmp_path):
    p = node_parameters(load_scenario("archi_demo"), tmp_path)["recorder"]
    assert p["compression"] == "lz4" and p["cpu_priority"] == "idle"      # config/recorder.yaml
    s = load_scenario("archi_demo", {"recorder": {"compression": "zstd", "flush_period_s": 2}})
    p = node_parameters(s, tmp_path)["recorder"]
    assert p["compression"] == "zstd" and p["flush_period_s"] == 2.0 and isinstance(p["flush_period_s"], float)
    assert p["output"] == str(tmp_path / "bag") and "drives/state" in p["tapped_topics"].split(",")


# What a node would refuse at start is refused when the scenario is loaded, through the
# node's own validation (ControllerConfig and the controller core, PlantParameters and
# Fault, GoughSensorModel), the merged parameters (node defaults < section) included.
@pytest.mark.parametrize("scenario, overrides, key, got", [
    ("mom3_square", {"controller": {"bandwidth_hz": "high"}}, "controller.bandwidth_hz: must be a number",
     "the string 'high'"),
    ("mom3_square", {"controller": {"distribution": "magic"}}, "controller.distribution: must be one of",
     "'magic'"),
    ("mom3_square", {"controller": {"bandwidth_hz": 5000}}, "controller.bandwidth_hz: must be in (0, 100] Hz",
     "5000"),
    ("mom3_square", {"controller": {"damping_ratio": 0.01}}, "controller.damping_ratio: must be in", "0.01"),
    ("mom3_square", {"controller": {"drive_mismatch_cycles": 2.5}},
     "controller.drive_mismatch_cycles: must be an integer", "2.5"),
    ("mom3_square", {"controller": {"continue_on_drive_failure": "yes"}},
     "controller.continue_on_drive_failure: must be true or false", "the string 'yes'"),
    ("mom3_square", {"controller": {"distribution": "two_arm"}}, "controller.distribution: must be two_arm only",
     "'two_arm'"),
    ("archi_fig12", {"plant": {"force_limit_n": math.nan}}, "plant.force_limit_n: must be", "nan"),
    ("archi_fig12", {"plant": {"force_limit_n": math.inf}}, "plant.force_limit_n: must be a finite number", "inf"),
    ("archi_fig12", {"plant": {"link_length_errors": [0.01, 0.02]}}, "plant.link_length_errors: must be 4 values",
     "(0.01, 0.02)"),
    ("archi_fig12", {"plant": {"compliance": 0.1}}, "plant.compliance: must be a list of finite numbers", "0.1"),
    ("archi_fig12", {"plant": {"faults": "2:broken:0.5"}}, "plant.faults: kind must be one of", "'broken'"),
    ("archi_fig12", {"plant": {"faults": "7:locked"}}, "plant.faults: drive must be in [0, 3]", "7 in '7:locked'"),
    ("archi_fig12", {"plant": {"faults": "locked"}}, "plant.faults: expected '<drive>:<kind>", "'locked'"),
    ("archi_fig12", {"plant": {"faults": ["2:locked"]}}, "plant.faults: must be a string", "['2:locked']"),
    ("mom3_square", {"sensor": {"noise_std_m": -1e-6}}, "sensor.noise_std_m: must be in [0, inf) m", "-1e-06"),
    ("mom3_square", {"sensor": {"resolution_m": 0.5}}, "sensor.resolution_m: must be in (0, 0.001] m", "0.5"),
    ("mom3_square", {"sensor": {"seed": -1}}, "sensor.seed: ", "-1"),
    ("mom3_square", {"trajectory": {"feed_override": math.nan}}, "trajectory.feed_override: must be a finite number",
     "nan"),
])
def test_bad_node_parameters_are_refused_when_loaded(scenario, overrides, key, got):
    with pytest.raises(ScenarioError) as refused:
        load_scenario(scenario, overrides)
    message = str(refused.value)
    assert message.startswith(key) and f"got {got}" in message, message


def test_a_load_over_the_plants_bound_is_refused_when_loaded():
    # PlantParameters.max_load_n (sim_hw_node would refuse its load_schedule at start)
    with pytest.raises(ScenarioError) as refused:
        load_scenario("archi_fig12", {"load": [{"t_s": 0.5, "wrench": [1e6, 0.0, 0.0]}]})
    assert str(refused.value).startswith("load: fx must be in") and str(refused.value).endswith(
        "got 1e+06 at t_s = 0.5 s")


def test_a_default_the_scenario_makes_invalid_is_named_as_the_nodes_default():
    # MoM3's default bandwidth (20 Hz) is over a tenth of the control rate at dt_s 0.01
    with pytest.raises(ScenarioError) as refused:
        load_scenario("mom3_square", {"dt_s": 0.01})
    assert str(refused.value) == ("controller.bandwidth_hz: must be in (0, 10] Hz (a tenth of the control rate), "
                                  "got 20.0 (not set by the scenario: the default of config/controller/mom3.yaml)")


def test_the_strategy_is_the_machines_default_when_the_scenario_sets_none(tmp_path):
    # config/controller/mom3.yaml runs sensor_space: it needs the Gough sensor
    path = tmp_path / "s.yaml"
    path.write_text("machine: mom3\nmetrology: false\nduration_s: 1\n")
    with pytest.raises(ScenarioError, match="^metrology: strategy sensor_space closes its loop"):
        load_scenario(path)


@pytest.mark.parametrize("text, message", [
    ("plant: {force_limit_n: 1e12}", "plant.force_limit_n: must be a number, got the string '1e12' "
                                     "(YAML reads 1e12 as a string: write 1.0e+12)"),
    ("plant: {force_limit_n: 1.0e12}", "plant.force_limit_n: must be a number, got the string '1.0e12' "
                                       "(YAML reads 1.0e12 as a string: write 1.0e+12)"),
    ("plant: {force_limit_n: '2000'}", "plant.force_limit_n: must be a number, got the string '2000' "
                                       "(quoted: write it without the quotes)"),
    ("plant: {link_length_errors: [0, 1e-3, 0, 0]}",
     "plant.link_length_errors: must be a list of finite numbers, at index 1 got the string '1e-3' "
     "(YAML reads 1e-3 as a string: write 1.0e-3)"),
    ("dt_s: 5e-4", "dt_s: must be a number in [1e-05, 0.1], got the string '5e-4' "
                   "(YAML reads 5e-4 as a string: write 5.0e-4)"),
])
def test_a_number_yaml_reads_as_a_string_says_what_to_write(tmp_path, text, message):
    path = tmp_path / "s.yaml"
    path.write_text(f"machine: archi\nduration_s: 1\ncontroller: {{strategy: joint_pid}}\n{text}\n")
    with pytest.raises(ScenarioError) as refused:
        load_scenario(path)
    assert str(refused.value) == message
    written = re.search(r"write (\S+)\)$", message)
    if written:                           # what it says to write is a float to YAML
        assert isinstance(yaml.safe_load(written.group(1)), float)


def _machine_file(tmp_path, name="archi"):
    data = yaml.safe_load((config_dir() / "machines" / "archi.yaml").read_text())
    data["name"] = name
    path = tmp_path / f"{name}_copy.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_machine_file_takes_the_controller_defaults_of_its_name(tmp_path, monkeypatch):
    by_name = node_parameters(load_scenario("archi_fig12"), tmp_path)["controller"]
    for given in (_machine_file(tmp_path), "archi_copy.yaml"):            # absolute, and from the working dir
        monkeypatch.chdir(tmp_path)
        s = load_scenario("archi_fig12", {"machine": str(given)})
        p = node_parameters(s, tmp_path)
        assert s.machine == str(tmp_path / "archi_copy.yaml") and s.machine_name == "archi"
        assert p["controller"]["distribution"] == "inf_norm"          # config/controller/archi.yaml's
        assert {k: v for k, v in p["controller"].items() if k != "machine"} == \
            {k: v for k, v in by_name.items() if k != "machine"}
        assert p["sim_hw"]["machine"] == p["controller"]["machine"] == s.machine


def test_a_machine_file_of_a_name_without_controller_defaults_runs_on_the_controllers_own(tmp_path):
    # as a machine of config/machines without config/controller/<name>.yaml does
    s = load_scenario("archi_fig12", {"machine": str(_machine_file(tmp_path, "archi_variant"))})
    assert s.machine_name == "archi_variant"
    assert "distribution" not in node_parameters(s, tmp_path)["controller"]      # ControllerConfig's


def test_a_machine_file_refuses_the_gough_sensor_which_takes_a_name(tmp_path):
    with pytest.raises(ScenarioError, match="^metrology: gough_sensor_node takes the name of a machine"):
        load_scenario("archi_demo", {"machine": str(_machine_file(tmp_path))})


def test_pkm_run_starts_nothing_on_a_bad_section(tmp_path, monkeypatch, capsys):
    from pkm_bringup import orchestrator

    def start(*_args, **_kwargs):
        raise AssertionError("the run was started")
    monkeypatch.setattr(orchestrator, "run_scenario", start)
    path = tmp_path / "bad.yaml"
    path.write_text("machine: archi\nduration_s: 1\ncontroller: {strategy: joint_pid, bandwidth_hz: high}\n")
    assert orchestrator.main([str(path), "--runs", str(tmp_path / "runs"), "--no-progress"]) == 2
    assert not (tmp_path / "runs").exists()
    assert "pkm-run: controller.bandwidth_hz: must be a number, got the string 'high'" in capsys.readouterr().err


def test_a_six_dof_machine_takes_six_component_loads_and_compliance(tmp_path):
    # (the shipped scenario's frame load goes with its plant section)
    s = load_scenario("hexapod_metrology", {"load": [{"t_s": 0.1, "wrench": [10.0, 0.0, -20.0, 1.0, 0.0, 2.0]}],
                                            "plant": {"compliance": [1e-6] * 3 + [1e-5] * 3}, "frame_load": []})
    assert s.load == [(0.1, 0.0, (10.0, 0.0, -20.0, 1.0, 0.0, 2.0))]
    flat = node_parameters(s, tmp_path)["sim_hw"]["load_profile"]
    assert flat == [0.1, 0.0, 10.0, 0.0, -20.0, 1.0, 0.0, 2.0]
    with pytest.raises(ScenarioError, match=r"load\[0\]: must be \{t_s: >= 0, wrench: \[6 finite numbers\]"):
        load_scenario("hexapod_metrology", {"load": [{"t_s": 0.1, "wrench": [10.0, 0.0, 0.0]}]})
    with pytest.raises(ScenarioError, match=r"mz must be in \[-500, 500\] N m \(max_load_nm\), got 600 at t_s = 0.1 s"):
        load_scenario("hexapod_metrology", {"load": [{"t_s": 0.1, "wrench": [0.0, 0.0, 0.0, 0.0, 0.0, 600.0]}]})
    with pytest.raises(ScenarioError, match=r"compliance: must be 6 values on hexapod8"):
        load_scenario("hexapod_metrology", {"plant": {"compliance": [1e-6, 0.0, 0.0]}, "frame_load": []})
    framed = load_scenario("hexapod_metrology", {"frame_load": [{"t_s": 0.2, "wrench": [0.0, 850.0, 0, 0, 0, 0]}],
                                                 "plant": {"frame_compliance": [7e-8] * 6}})
    assert node_parameters(framed, tmp_path)["sim_hw"]["frame_load_profile"] == [0.2, 0.0, 0.0, 850.0, 0, 0, 0, 0]
    with pytest.raises(ScenarioError, match=r"frame_compliance: must be 6 values on hexapod8"):
        load_scenario("hexapod_metrology", {"frame_load": [{"t_s": 0.2, "wrench": [0.0, 850.0, 0, 0, 0, 0]}],
                                            "plant": {"frame_compliance": [7e-8] * 3}})


def test_a_scenario_that_is_no_text_or_an_alias_bomb_is_refused_by_name(tmp_path):
    """A non-UTF-8 scenario ended in a UnicodeDecodeError traceback; a "billion laughs"
    in its name passed 3 GB. Each is refused with the file named, in well under a second."""
    import time
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"name: caf\xe9\nmachine: archi\n")
    with pytest.raises(ScenarioError, match=r"binary.yaml: not UTF-8 text \(byte 9"):
        load_scenario(binary)
    nul = tmp_path / "nul.yaml"
    nul.write_bytes(b"machine: archi\x00\n")
    with pytest.raises(ScenarioError, match="contains a NUL byte"):
        load_scenario(nul)
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]" for k in range(1, 9)]
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join(lines) + "\nname: *a8\nmachine: archi\nduration_s: 1.0\n")
    start = time.perf_counter()
    with pytest.raises(ScenarioError, match="more than 1000000 values once its aliases are expanded"):
        load_scenario(bomb)
    assert time.perf_counter() - start < 5.0
    looping = tmp_path / "loop.yaml"
    looping.write_text("name: &n [*n]\nmachine: archi\n")
    with pytest.raises(ScenarioError, match="aliases are expanded"):
        load_scenario(looping)


def test_a_machine_file_that_is_no_text_is_refused_by_name(tmp_path):
    from pkm_kinematics import load_machine
    from pkm_kinematics.yaml_files import UnreadableFileError
    path = tmp_path / "m.yaml"
    path.write_bytes(b"\xff\xfe kind: planar\n")
    with pytest.raises(UnreadableFileError, match=r"m.yaml: not UTF-8 text"):
        load_machine(path)


@pytest.mark.parametrize("trajectory, words", [
    ({"rate_hz": 1e6}, r"trajectory.rate_hz: must be in \[1, 20000\] Hz, got 1000000.0"),
    ({"max_segments": 0}, r"trajectory.max_segments: must be an integer >= 1"),
])
def test_the_planners_rate_and_budget_are_refused_before_anything_starts(trajectory, words):
    """rate_hz 1e6 was refused only by trajectory_node, once the graph had started."""
    with pytest.raises(ScenarioError, match=words):
        load_scenario("archi_demo", {"trajectory": trajectory})


def test_a_rate_the_can_bus_cannot_carry_is_refused_naming_the_figures():
    """archi_canopen at 1 kHz: four drives' cycle takes 1355 bits at 1 Mbit/s, 1.358 ms with
    their heartbeats' share (bus_timing)."""
    with pytest.raises(ScenarioError) as info:
        load_scenario("archi_canopen", {"dt_s": 0.001})
    text = str(info.value)
    assert text.startswith("dt_s: the CAN bus cannot carry the cycle") and "1355 bits" in text \
        and "1.358 ms at 1 Mbit/s" in text and "asks for 1 ms" in text, text
    # a slower bus needs a longer period still
    with pytest.raises(ScenarioError, match=r"drives.can_bitrate|dt_s: the CAN bus"):
        load_scenario("archi_canopen", {"drives": {"can_bitrate": 500000}})


@pytest.mark.parametrize("drives,message", [
    ({"drive_faults": "7:over_current"}, "drives.drive_faults: drive in [0, 3]"),
    ({"drive_faults": "1:melted"}, "drives.drive_faults: expected '<drive>:<kind>"),
    ({"pdo_timeout_s": "fast"}, "drives.pdo_timeout_s: must be a number"),
    ({"node_ids": [1, 2]}, "drives.node_ids: not a drives parameter"),
])
def test_bad_drives_sections_are_refused(drives, message):
    with pytest.raises(ScenarioError) as info:
        load_scenario("archi_canopen", {"drives": drives})
    assert str(info.value).startswith(message), str(info.value)


def test_canopen_scenarios_wire_the_drive_interface_and_the_virtual_drives(tmp_path):
    s = load_scenario("archi_canopen")
    p = node_parameters(s, tmp_path)
    assert "sim_hw" not in p and s.machine_node == "drives"
    assert p["drives"]["can_interface"] == "remote" and p["drives"]["can_channel_file"] == \
        p["virtual_drives"]["bridge_url_file"] == str(tmp_path / "can_bus.url")
    assert p["virtual_drives"]["compliance"] == [5.0e-7, 5.0e-7, 2.0e-6]     # the scenario's plant section
    assert p["drives"]["command_source"] == "/pkm/controller" and "virtual" not in p["drives"]
    assert "mode" not in p["virtual_drives"] and p["virtual_drives"]["dt_s"] == 0.002
    real = load_scenario("archi_canopen", {"drives": {"virtual": False}, "metrology": False, "load": [],
                                           "controller": {"strategy": "computed_torque"}})
    pr = node_parameters(real, tmp_path)
    assert "virtual_drives" not in pr and "can_channel_file" not in pr["drives"]


def test_incremental_encoders_need_the_machines_homing():
    with pytest.raises(ScenarioError, match=r"plant.encoder_offsets_m: incremental encoders must be homed: "
                                            r"machine 'sliding_star' has no drives.homing"):
        load_scenario("archi_demo", {"machine": "sliding_star", "metrology": False, "program": None,
                                     "duration_s": 0.1, "load": [], "controller": {"strategy": "computed_torque"},
                                     "plant": {"encoder_offsets_m": [0.01, 0.02, 0.03, 0.04]}})
    homed = load_scenario("archi_demo", {"plant": {"encoder_offsets_m": [0.01, 0.02, 0.03, 0.04]}})
    assert homed.plant["encoder_offsets_m"] == [0.01, 0.02, 0.03, 0.04]


def test_a_calibrated_model_drives_the_controller_and_planner_while_the_plant_keeps_the_machine(tmp_path):
    """``model``: the controller and the planner load the calibrated file (relative to
    the scenario), the plant and the sensor the machine with its errors; the
    controller's status names the model; a model of other legs is refused by name."""
    data = yaml.safe_load((config_dir() / "machines" / "archi.yaml").read_text())
    data["legs"][2]["link_length"] = 1.02
    data["calibration"] = {"label": "test run"}
    (tmp_path / "archi.calibrated.yaml").write_text(yaml.safe_dump(data))
    scenario = tmp_path / "s.yaml"
    scenario.write_text("machine: archi\nmodel: archi.calibrated.yaml\nprogram: "
                        f"{config_dir() / 'programs' / 'archi_test_motion.nc'}\n"
                        "plant: {link_length_errors: [0, 0, 0.02, 0]}\n")
    s = load_scenario(scenario)
    p = node_parameters(s, tmp_path)
    model = str(tmp_path / "archi.calibrated.yaml")
    assert (p["controller"]["machine"], p["trajectory"]["machine"]) == (model, model)
    assert p["sim_hw"]["machine"] == "archi" and list(p["sim_hw"]["link_length_errors"]) == [0, 0, 0.02, 0]
    from pkm_controller.controller import ControllerCore
    from pkm_kinematics import load_machine
    values = ControllerCore(load_machine(model)).status()[2]
    assert values["model"] == "archi (calibrated: test run)", values["model"]
    assert ControllerCore(load_machine("archi")).status()[2]["model"] == "archi (nominal)"
    with pytest.raises(ScenarioError, match="^model: genhexkins is a struts machine with legs .* it does not "
                                            "match the machine archi"):
        load_scenario(scenario, {"model": "genhexkins"})


def test_a_lockstep_run_whose_program_the_controller_refused_is_not_completed(tmp_path):
    """The controller held still (its program refused at the start): the run failed,
    saying why, not 'completed' (archi_calibration without its initial pose did that)."""
    import json
    from pkm_bringup.orchestrator import collect
    s = load_scenario("archi_demo")
    (tmp_path / "summaries").mkdir()
    fault = ("trajectory refused: it starts at [1.0, -0.4, 0.785398], 12.129 mm / 0.0463 rad from the current "
             "reference [0.995043, -0.38893, 0.831722] (start_tolerance_m 0.005, start_tolerance_rad 0.04)")
    (tmp_path / "summaries" / "controller.json").write_text(json.dumps({"faults": fault, "cause": "none"}))
    run = collect(s, tmp_path, "lockstep", 1.0, {})
    assert run["status"] == "failed" and run["error"] == f"the program did not run: the controller {fault}", run
    (tmp_path / "summaries" / "controller.json").write_text(json.dumps({"faults": "none", "cause": "none"}))
    assert collect(s, tmp_path, "lockstep", 1.0, {})["status"] == "completed"
