"""The strategy registry (pkm_controller.strategies): every entry builds a controller
that waits for the input its feedback names, and an unknown name is refused with the
known ones."""

import pytest

from pkm_kinematics import load_machine
from pkm_controller.config import ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.lockstep import StampPairing
from pkm_controller.strategies import NAMES, REGISTRY, Feedback, Law, Projection, strategy


@pytest.mark.parametrize("name", NAMES)
def test_every_strategy_builds_a_core_that_waits_for_its_feedback(name):
    s = strategy(name)
    core = ControllerCore(load_machine("mom3"), ControllerConfig(strategy=name))
    assert core.strategy is s
    assert (core.metrology is not None) == s.uses_metrology == bool(s.metrology_topic) == bool(s.reading)
    assert isinstance(core.integral, list) == s.joint_space          # one integral per drive, or per task axis
    assert StampPairing(s.uses_metrology, s.reading).needs_reading == s.uses_metrology


def test_the_registry_holds_the_papers_strategies():
    assert NAMES == ("joint_pid", "decentralized_projected", "decentralized_integral_projected", "cartesian_pid",
                     "computed_torque", "sensor_space", "measured_space")
    assert {n for n, s in REGISTRY.items() if s.uses_metrology} == {"sensor_space", "measured_space"}
    assert REGISTRY["sensor_space"].metrology_topic == "metrology/struts"
    assert REGISTRY["measured_space"].feedback == Feedback.GOUGH_POSE
    assert {n: s.projection for n, s in REGISTRY.items() if s.projection != Projection.NONE} == {
        "decentralized_projected": Projection.FORCES, "decentralized_integral_projected": Projection.INTEGRAL}
    assert all(s.joint_space for s in REGISTRY.values() if s.projection != Projection.NONE)
    assert {s.law for s in REGISTRY.values()} == set(Law)


@pytest.mark.parametrize("bad", ["magic", "", None, "Sensor_Space"])
def test_an_unknown_strategy_is_refused_naming_the_known_ones(bad):
    with pytest.raises(ValueError, match=r"strategy: must be one of \['joint_pid'"):
        strategy(bad)
    with pytest.raises(ValueError, match="strategy: must be one of"):
        ControllerCore(load_machine("archi"), ControllerConfig(strategy=bad))
