"""The public machine interface (pkm_kinematics.machine.ParallelMachine): every seed
machine satisfies it, and its bar geometry agrees with the machines' own definitions
(each bar as long as its link, each carriage on its rail at the drive position)."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.machine import ParallelMachine

MACHINES = ("archi", "sliding_star", "orthoglide", "mom3")


@pytest.mark.parametrize("name", MACHINES)
def test_every_machine_has_the_public_interface(name):
    assert isinstance(load_machine(name).model, ParallelMachine)


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
