"""Parallel singularities of the translational machines (Orthoglide §3.3, det A = 0):
the measure, its independent check (J_m = B^-1 A loses rank there), and the poses
refused near one by the kinematics, the trajectory validation and the config."""

import copy
import dataclasses

import numpy as np
import pytest
import yaml

from pkm_kinematics import ConfigError, config_dir, load_machine, load_machine_data
from pkm_kinematics.errors import SingularityError
from pkm_trajectory.planner import Limits, Line, TrajectoryRejected, plan, validate

ORTHO = load_machine("orthoglide").model
DIAGONAL = np.linspace(0.1, 0.21, 1101)          # x = y = z = t, from inside the cube to past Q2


def test_the_measure_is_one_at_the_isotropic_point_and_above_the_margin_on_the_cube():
    assert ORTHO.parallel_singularity_measure(ORTHO.home) == pytest.approx(1.0, abs=1e-12)
    center, half = ORTHO.workspace["center"], ORTHO.workspace["size"] / 2.0
    for corner in (center - half, center + half):             # Q1, Q2: the cube's closest points (§4.4)
        assert ORTHO.parallel_margin < ORTHO.parallel_singularity_measure(corner) < 0.7
    ORTHO.check_parallel_singularity(center + half)            # inside: no error


def test_the_measure_vanishes_where_the_jacobian_loses_rank():
    poses = np.stack([DIAGONAL] * 3, axis=1)
    measure = ORTHO.parallel_singularity_measure_batch(poses)
    k = int(np.nanargmin(measure))
    assert measure[k] < 1e-3
    cond = np.linalg.cond(ORTHO.jacobian(poses[k]))            # the independent reference: cond(J_m)
    assert cond > 1e3 and np.linalg.cond(ORTHO.jacobian(poses[0])) < 10.0
    with pytest.raises(SingularityError, match=r"near a parallel singularity \(Orthoglide §3.3"):
        ORTHO.check_parallel_singularity(poses[k])


def test_a_trajectory_into_a_parallel_singularity_is_refused_naming_it():
    """The Orthoglide's joint limits stop it before this singularity (0.18 m along the
    diagonal, the limits at 0.13 m: its design keeps the singularities out of reach);
    without them and without the transmission bounds, this check is what refuses."""
    legs = [dataclasses.replace(leg, joint_limits=(-np.inf, np.inf)) for leg in ORTHO.legs]
    unbounded = dataclasses.replace(ORTHO, legs=legs, transmission_bounds=None)
    limits = Limits((1.0,) * 3, (10.0,) * 3, (500.0,) * 3)
    samples = plan([Line(np.zeros(3), np.full(3, 0.17))], limits, translation_axes=3)
    with pytest.raises(TrajectoryRejected, match=r"near a parallel singularity.*parallel_margin 0.2"):
        validate(samples, unbounded)
    validate(samples, dataclasses.replace(unbounded, parallel_margin=0.0), max_condition=None)   # off: accepted


@pytest.mark.parametrize("value", [-0.1, 1.0, "high"])
def test_parallel_margin_out_of_range_names_the_field(value):
    with open(config_dir() / "machines" / "orthoglide.yaml") as fh:
        data = copy.deepcopy(yaml.safe_load(fh))
    data["parallel_margin"] = value
    with pytest.raises(ConfigError, match="parallel_margin"):
        load_machine_data(data)
