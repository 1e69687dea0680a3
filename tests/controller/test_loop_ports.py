"""The sans-IO loops' ports are declared (typing.Protocol): each loop asks its ports
for nothing else, and each node implements every one (issue 41, "one loop, three
shells": a replay or a study engine implements the same Protocol)."""

import re
from pathlib import Path

import pytest

from pkm_controller.controller_node import ControllerNode
from pkm_controller.node_loop import ControllerPorts
from pkm_sim_hw.sim_hw_node import SimHwNode
from pkm_sim_hw.sim_loop import SimPorts

SRC = Path(__file__).resolve().parents[2] / "src"


def members(protocol) -> set[str]:
    return {name for name in vars(protocol) if not name.startswith("_")}


@pytest.mark.parametrize("protocol, loop_file, node", [
    (ControllerPorts, "pkm_controller/pkm_controller/node_loop.py", ControllerNode),
    (SimPorts, "pkm_sim_hw/pkm_sim_hw/sim_loop.py", SimHwNode)])
def test_the_loop_asks_only_its_declared_ports_and_the_node_implements_them(protocol, loop_file, node):
    used = set(re.findall(r"self\.ports\.([a-z_]+)", (SRC / loop_file).read_text()))
    assert used and used <= members(protocol), used - members(protocol)
    # a method of the node's class, or a publisher's bound method it sets at configure
    # (controller_node: the tapped publishers, called without a wrapper each cycle)
    source = Path(__import__(node.__module__, fromlist=["_"]).__file__).read_text()
    missing = [name for name in members(protocol) if not callable(getattr(node, name, None))
               and f"self.{name} = " not in source]
    assert not missing, missing
