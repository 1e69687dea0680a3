"""Calibrating ARCHI in three commands, end to end in the graph: the shipped calibration
program (pkm-calibrate plan's, checked to be what plan writes today) run on the machine
with archi_fig12's 2 % leg error, `pkm-calibrate identify` on the recording, and the
calibrated file as the controller's model: archi_fig12's joint PIDs no longer fight.
A run of another machine and a run without dwells (of the length asked) are refused by name."""

import re

import numpy as np
import pytest
import yaml

from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_calibration.cli import main
from pkm_kinematics import load_machine
from pkm_kinematics.config import config_dir
from pkm_runs.report_data import load_run


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    root = tmp_path_factory.mktemp("calibration")
    run = run_scenario(load_scenario("archi_calibration"), root / "run", in_process=True, progress=False,
                       report=False)
    return root, run


def test_the_shipped_program_is_what_plan_writes(tmp_path):
    out = tmp_path / "plan.nc"
    assert main(["plan", "archi", "--poses", "30", "--angle-half-range-deg", "180", "--dwell-s", "0.6",
                 "--feed", "30000", "--out", str(out)]) == 0
    shipped = (config_dir() / "programs" / "archi_calibration.nc").read_text()
    assert out.read_text() == shipped


def test_identify_finds_the_leg_error_and_the_calibrated_model_stops_the_fight(calibration, capsys):
    root, run = calibration
    assert run["status"] == "completed", run["error"]
    out = root / "archi.calibrated.yaml"
    assert main(["identify", "archi", str(root / "run"), "--out", str(out), "--label", "test"]) == 0
    printed = capsys.readouterr().out
    dwells = re.search(r"no instrument, (\d+) dwells(?: \((\d+) left out: the machine had not settled\))?", printed)
    assert dwells and int(dwells[1]) + int(dwells[2] or 0) == 30 and int(dwells[2] or 0) <= 3, printed
    assert "held at nominal: b.y.q2, zero.q4, b.x.q4, b.y.q4, rail.across.q4" in printed, printed
    data = yaml.safe_load(out.read_text())
    length = data["legs"][2]["link_length"]
    std = data["calibration"]["parameters"]["length.q3"]["std"]
    assert abs(length - 1.02) < 3 * std and std < 5e-5, (length, std)      # 1 um counts: tens of um
    assert load_machine(out).model_label == "archi (calibrated: test)"
    with capsys.disabled():           # the run's nodes write to the real standard streams
        fig12 = run_scenario(load_scenario("archi_fig12", {"model": str(out), "controller": {"strategy": "joint_pid"}}),
                             root / "fig12", in_process=True, progress=False, report=False)
    assert fig12["status"] == "completed" and fig12["model"] == str(out), (fig12["status"], fig12["error"])
    applied = load_run(root / "fig12").steps.rows["state"].effort
    assert np.abs(applied).max() < 400.0, np.abs(applied).max()       # nominal model: 2000 N, saturated


def test_runs_that_are_not_this_machines_calibration_are_refused(calibration, capsys):
    root, _ = calibration
    assert main(["identify", "genhexkins", str(root / "run"), "--instrument", "laser"]) == 2
    assert "a run of archi, not of genhexkins" in capsys.readouterr().err        # its run.json says so
    assert main(["identify", "archi", str(root / "run"), "--min-dwell-s", "5"]) == 2
    assert "0 dwells of at least 5 s found, 21 needed (is it a calibration program's run?)" in \
        capsys.readouterr().err
