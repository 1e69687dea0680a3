"""Batched maps: reachability, conditioning and singularity margin."""

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.analysis import (condition_map, condition_numbers, reachability, singularity_margin,
                                     workspace_grid)

ARCHI = load_machine("archi").model
ORTHO = load_machine("orthoglide").model


def test_maps_agree_with_single_pose_calls():
    poses = np.array([[1.0, -0.4, 0.3],      # inside
                      [1.0, -1.3, 0.0],      # a link cannot reach
                      [2.9, -0.4, 0.0],      # q2 beyond its joint limit
                      [0.9, -0.3, 4.0]])     # unlimited rotation: still fine
    reach = reachability(ARCHI, poses)
    assert reach.tolist() == [True, False, False, True]
    cond = condition_map(ARCHI, poses)
    assert np.isnan(cond[1]) and np.isnan(cond[2])
    for k in (0, 3):
        assert cond[k] == pytest.approx(ARCHI.condition_number(poses[k]), rel=1e-12)


def test_singularity_margin():
    # isotropic Orthoglide: margin 1; ARCHI sub-machine J_124 at its singular angle: ~0
    assert singularity_margin(ORTHO.jacobian_batch(np.zeros((1, 3))))[0] == pytest.approx(1.0)
    jac = ARCHI.jacobian_batch(np.array([[1.0, -0.4, np.radians(-150.0)]]))[:, [0, 1, 3], :]
    assert singularity_margin(jac)[0] < 1e-12
    assert np.isinf(condition_numbers(np.zeros((1, 3, 3))))[0]


def test_workspace_grid_covers_the_configured_box():
    grid = workspace_grid(ARCHI, points_per_axis=3, theta_points=5)
    assert grid.shape == (45, 3)
    assert grid[:, 0].min() == ARCHI.workspace["x"][0] and grid[:, 0].max() == ARCHI.workspace["x"][1]
    assert np.degrees(grid[:, 2]).max() == pytest.approx(ARCHI.workspace["theta_deg"][1])
