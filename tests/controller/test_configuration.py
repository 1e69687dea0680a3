"""controller_node's decisions without rclpy: the core from parameters, the metrology
inputs, the summary."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from pkm_controller.configuration import core_from_parameters, metrology_inputs, run_summary
from pkm_controller.config import ControllerConfig
from pkm_kinematics.config import config_dir


@pytest.mark.parametrize("machine, config, message", [
    ("no_such_machine", ControllerConfig(), "parameter 'machine': "),
    ("archi", ControllerConfig(bandwidth_hz=900.0), r"parameter 'bandwidth_hz': must be in \(0, 100\] Hz"),
    ("mom3", ControllerConfig(distribution="two_arm"), "parameter 'distribution': must be two_arm only on a planar"),
])
def test_a_bad_value_is_named_as_the_nodes_parameter(machine, config, message):
    with pytest.raises(ValueError, match=message):
        core_from_parameters(machine, config)


def test_a_machine_the_core_cannot_run_is_named_as_the_machine_parameter(tmp_path):
    data = yaml.safe_load((config_dir() / "machines" / "archi.yaml").read_text())
    del data["dynamics"]
    path = tmp_path / "no_dynamics.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ValueError, match="^parameter 'machine': machine 'archi': the controller needs a 'dynamics'"):
        core_from_parameters(str(path), ControllerConfig())


def test_a_good_configuration_gives_the_core():
    core = core_from_parameters("archi", ControllerConfig(strategy="sensor_space", distribution="inf_norm"))
    assert core.n == 4 and core.metrology is not None and core.config.distribution == "inf_norm"


def test_metrology_inputs_per_strategy():
    struts = SimpleNamespace(position=[0.5] * 6)
    assert metrology_inputs("struts", struts) == ([0.5] * 6, None)
    assert metrology_inputs(None, None) == (None, None)
    half = math.sqrt(0.5)                                         # 90 deg about z
    pose = SimpleNamespace(position=[1.0, 2.0, 3.0], orientation=[0.0, 0.0, half, half])
    _, (position, rotation) = metrology_inputs("pose", pose)
    assert position == [1.0, 2.0, 3.0]
    np.testing.assert_allclose(rotation, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    with pytest.raises(ValueError, match="^metrology/pose: "):
        metrology_inputs("pose", SimpleNamespace(position=[math.nan, 0.0, 0.0], orientation=[0.0, 0.0, 0.0, 1.0]))


def test_the_run_summary_carries_the_status_and_the_timing():
    core = core_from_parameters("mom3", ControllerConfig())
    summary = run_summary(core, [100e-6, 200e-6, 300e-6], [], 7)
    assert summary["stopped"] is False and summary["cycles"] == 0
    assert summary["compute_us_p50"] == pytest.approx(200.0) and math.isnan(summary["response_us_p50"])
    assert summary["published"] == {"drives/command": 7, "controller/reference": 7}
