"""Pose selection by Borm & Menq's observability index O1, and the calibration program
pkm-calibrate writes: the chosen poses beat random ones of the same number (O1 and the
predicted covariance), and the program plans on the machine as any program."""

import numpy as np
import pytest

from pkm_calibration.cli import main
from pkm_calibration.identify import identifiability
from pkm_calibration.poses import calibration_program, candidate_poses, observability_index, select_poses
from pkm_calibration.strut_errors import StrutErrorModel
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_trajectory.planner import Limits, plan_validated
from pkm_trajectory.program import gcode_segments

LIMITS = Limits((0.1,) * 3 + (0.5,) * 3, (1.0,) * 3 + (5.0,) * 3, (40.0,) * 3 + (200.0,) * 3)


@pytest.fixture(scope="module")
def setup():
    machine = load_machine("genhexkins").model
    model = StrutErrorModel(machine, (0.0, 0.0, -0.05))
    candidates = candidate_poses(machine, 300, 1)
    q, _ = machine.inverse_kinematics_batch(candidates)
    jac = model.jacobian(np.zeros(model.size), q)
    free = list(identifiability(jac, model.names).identified)
    blocks = jac[:, free].reshape(len(candidates), 3, len(free)) / np.linalg.norm(jac[:, free], axis=0)
    return machine, candidates, blocks


def test_the_chosen_poses_beat_random_ones(setup):
    _, _, blocks = setup
    chosen = select_poses(blocks, 30)
    assert len(set(chosen)) == 30

    def o1(idx):
        return observability_index(blocks[idx].reshape(-1, blocks.shape[2]))

    def spread(idx):
        j = blocks[idx].reshape(-1, blocks.shape[2])
        return np.trace(np.linalg.inv(j.T @ j))
    rng = np.random.default_rng(0)
    draws = [list(rng.choice(len(blocks), 30, replace=False)) for _ in range(20)]
    assert o1(chosen) > 1.3 * np.median([o1(d) for d in draws]) and o1(chosen) > max(o1(d) for d in draws)
    assert spread(chosen) < 0.5 * np.median([spread(d) for d in draws])


def test_the_calibration_program_plans_on_the_machine(setup):
    machine, candidates, blocks = setup
    chosen = select_poses(blocks, 16)
    text = calibration_program(machine.task_space, candidates[chosen], dwell_s=0.3)
    assert text.count("G4 P0.3") == 16
    segments = gcode_segments(text, machine.task_space, machine.home)
    samples = plan_validated(segments, machine, LIMITS, 100.0, 0.0, 2.0, 50.0)      # 100 Hz: a hexapod's samples
    ends = [s.end for s in segments if hasattr(s, "start")]
    assert np.allclose(ends, candidates[chosen], atol=1e-7)        # 0.1 um, 1e-5 deg: the program's digits
    assert samples.duration_s > 16 * 0.3


def test_pkm_calibrate_plan_writes_the_program_and_refuses_what_it_cannot(setup, tmp_path, capsys):
    out = tmp_path / "calibration.nc"
    assert main(["plan", "genhexkins", "--poses", "20", "--candidates", "150", "--tool", "0", "0", "-0.05",
                 "--out", str(out)]) == 0
    text = out.read_text()
    assert "O1" in text and text.count("G4 P") == 20
    assert main(["plan", "orthoglide"]) == 2
    assert "self-calibration of a planar machine on rails" in capsys.readouterr().err
    with pytest.raises(FieldError, match="at least 15 poses"):
        select_poses(setup[2], 10)          # 45 parameters: 3 measurements a pose


def test_a_workspace_outside_the_strut_limits_is_refused_not_drawn_forever():
    from pkm_kinematics.struts import StrutMachine
    m = load_machine("genhexkins").model
    tight = StrutMachine(m.name, m.leg_names, m.base_joints, m.platform_joints, [[0.1, 0.2]] * 6, m.home, m.workspace)
    with pytest.raises(FieldError, match="0 of 200 poses drawn in the workspace are within the joint limits"):
        candidate_poses(tight, 10, 0)
