"""The public machine interface (pkm_kinematics.machine): every machine file of
config/machines satisfies the Protocols its model's class claims, and no more; a
sub-machine's condition number agrees with the machine's own measure; and the bar
geometry of the rail machines agrees with their definitions (each bar as long as its
link, each carriage on its rail at the drive position)."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine, machine_names
from pkm_kinematics.machine import ControlledMachine, ParallelMachine, RailActuated, SpatialMachine

ALL = machine_names()
MACHINES = ("archi", "sliding_star", "orthoglide", "mom3")          # the rail machines of the seeds
PROTOCOLS = (ParallelMachine, ControlledMachine, RailActuated, SpatialMachine)
CLAIMS = {"RailMachine": {ParallelMachine, ControlledMachine, RailActuated},
          "StrutMachine": {ParallelMachine, ControlledMachine, SpatialMachine},
          "ParallelogramMachine": {ParallelMachine}}         # a plant's model: not controlled


def test_every_machine_file_is_checked():
    assert len(ALL) >= 7 and {"genhexkins", "hexapod8", "mom3_imperfect"} <= set(ALL), ALL


@pytest.mark.parametrize("name", ALL)
def test_every_machine_has_the_interface_of_its_kind(name):
    model = load_machine(name).model
    kind = type(model).__name__
    assert kind in CLAIMS, f"{name}: a machine class no Protocol set is claimed for: {kind}"
    has = {p for p in PROTOCOLS if isinstance(model, p)}
    missing = {p.__name__ for p in CLAIMS[kind] - has}
    assert not missing, f"{name} ({kind}) lacks what {sorted(missing)} ask"
    assert has == CLAIMS[kind], f"{name} ({kind}) also satisfies {sorted(p.__name__ for p in has - CLAIMS[kind])}"


@pytest.mark.parametrize("name", ALL)
def test_rows_condition_of_all_rows_is_the_machines_condition_number(name):
    """Against numpy's SVD condition number where the machine has no weighting of its own
    (the 3-DOF machines), and against condition_number where it has (a hexapod's
    rotation columns weighted by its characteristic length)."""
    model = load_machine(name).model
    rng = np.random.default_rng(5)
    home = np.asarray(model.home, dtype=float)
    for _ in range(4):
        x = home + rng.uniform(-0.003, 0.003, home.shape)
        jac = model.jacobian(x)
        reference = model.condition_number(x) if isinstance(model, SpatialMachine) else np.linalg.cond(jac)
        assert model.rows_condition(jac) == pytest.approx(reference, rel=1e-7), (name, x)
    assert model.rows_condition(jac[:model.task_dof - 1]) == math.inf     # rows that cannot span the task


@pytest.mark.parametrize("name", MACHINES)
def test_each_bar_joins_its_carriage_to_its_platform_joint_at_its_length(name):
    config = load_machine(name)
    model = config.model
    rng = np.random.default_rng(3)
    links = [leg["link_length"] for leg in config.data["legs"]]
    for _ in range(5):
        x = np.asarray(model.home, dtype=float) + rng.uniform(-0.005, 0.005, 3)     # m (and rad for theta)
        q = model.inverse_kinematics(x, check_limits=False)
        carriages, joints = model.leg_joints(x)
        np.testing.assert_allclose([math.dist(a, b) for a, b in zip(carriages, joints)], links, atol=1e-12)
        dim = model.rail_origins.shape[1]
        np.testing.assert_allclose(carriages[:, :dim], model.rail_origins + q[:, None] * model.rail_directions,
                                   atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(model.rail_directions, axis=1), 1.0, atol=1e-15)
