"""Scenario files -> node parameters (pure; no ROS graph)."""

import re
from pathlib import Path

import pytest
import yaml

from pkm_bringup.scenario import ScenarioError, load_scenario, node_parameters, params_file_text
from pkm_kinematics.config import config_dir

SCENARIOS = sorted((config_dir() / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_shipped_scenarios_load(path, tmp_path):
    s = load_scenario(path)
    params = node_parameters(s, tmp_path)
    assert s.duration_s > 0
    assert params["sim_hw"]["machine"] == params["controller"]["machine"] == s.machine
    for name, values in params.items():   # every file is a valid --params-file
        data = yaml.safe_load(params_file_text(values))
        assert data["/**"]["ros__parameters"] == values, name


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
    assert p["sim_hw"]["load_schedule"] == [0.0, 1.0, 2.0, 3.0]
    assert "link_length_errors" not in p["sim_hw"]          # ARCHI-sized default dropped for MoM3
    assert p["controller"]["wait_for_trajectory"] is True and p["controller"]["wait_for_start"] is False
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


def test_a_ramp_may_end_exactly_where_the_next_entry_starts():
    s = load_scenario("mom3_square", {"dt_s": 0.001, "load": [
        {"t_s": 0.1, "wrench": [10.0, 0.0, 0.0], "ramp_s": 0.2}, {"t_s": 0.3, "wrench": [0.0, 0.0, 0.0]}]})
    assert len(s.load) == 201 and s.load[199][1][0] == pytest.approx(10.0) and s.load[-1] == (0.3, (0.0, 0.0, 0.0))


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
